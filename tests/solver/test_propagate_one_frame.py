"""The top-down pass of one frame in plain floats (limb_placement._propagate_one_frame) against the numpy pass on
that frame: every field of the result equal bit for bit on the full metarig, with a box in the way, a hand
beyond reach, a foot held short by its limits, poles, and hands and feet turned toward wanted orientations."""

import numpy as np
import pytest

from fullbody_adjust.solver.fullbody.adjust import adjust_frames
from fullbody_adjust.solver.fullbody.limb_placement import LimbPlacement
from tests.helpers import metarig
from tests.solver.test_stacked_limbs import FIELDS, _four_limbs_case


@pytest.fixture(scope="module")
def rig():
    return metarig.load()


def _turns(rng, n):
    """Wanted world rotation deltas (n,E,3,3) of the hands and feet, NaN (none) for about a third of them."""
    q = rng.normal(size=(n, len(metarig.EFFECTORS), 4))
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = np.moveaxis(q, -1, 0)
    turns = np.stack([np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
                      np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
                      np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1)], -2)
    turns[rng.random((n, len(metarig.EFFECTORS))) < 0.3] = np.nan
    turns[:, -1] = np.nan  # the head takes no end turn
    return turns


@pytest.mark.parametrize("per_frame_boxes", [False, True])
@pytest.mark.parametrize("with_turns", [False, True])
def test_one_frames_pass_gets_the_bits_of_the_numpy_pass(monkeypatch, rig, per_frame_boxes, with_turns):
    model, heads, tails, targets, boxes, x, poles = _four_limbs_case(rig, per_frame_boxes)
    turns = _turns(np.random.default_rng(3), len(targets)) if with_turns else None
    for f in range(len(targets)):
        frame_boxes = boxes if not per_frame_boxes else type(boxes)(boxes.mins[f:f + 1], boxes.maxs[f:f + 1])
        args = (model, heads[f:f + 1], tails[f:f + 1], targets[f:f + 1], metarig.EFFECTORS, metarig.PRIORITIES)
        kwargs = dict(obstacles=frame_boxes, bone_x_axes=x[f:f + 1], poles=poles[f:f + 1],
                      end_turns=None if turns is None else turns[f:f + 1])
        plain = adjust_frames(*args, **kwargs)
        with monkeypatch.context() as numpy_pass:
            numpy_pass.setattr(LimbPlacement, "_propagate_one_frame", LimbPlacement._propagate_frames)
            expected = adjust_frames(*args, **kwargs)
        for field in FIELDS:
            a, b = np.asarray(getattr(plain, field)), np.asarray(getattr(expected, field))
            if a.dtype.kind == "f":
                np.testing.assert_array_equal(a.view(np.int64), b.view(np.int64), err_msg=f"frame {f}: {field}")
            else:
                assert a.tolist() == b.tolist(), f"frame {f}: {field}"
        assert plain.moved.any()
