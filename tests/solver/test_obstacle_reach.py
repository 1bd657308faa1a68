"""Which obstacles a solve can meet (solver/obstacles/reach.py) on the Rigify full human metarig: the skeleton's
reach is the longest path from the root along the bones, every solved bone stays inside the ball body_reach gives,
boxes outside it are left out, and a solve with far boxes added is the solve without them, bit for bit."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from fullbody_adjust.solver import Boxes
from fullbody_adjust.solver.fullbody.adjust import adjust_frames, adjust_pose
from fullbody_adjust.solver.body.model import FIXED
from fullbody_adjust.solver.obstacles.reach import body_reach, reachable_boxes, skeleton_reach
from tests.helpers import metarig


@pytest.fixture(scope="module")
def rig():
    return metarig.load()


def _walked_reach(model, heads, tails):
    """skeleton_reach the long way: from each moving bone up to the root, one parent at a time."""
    best = 0.0
    for j in range(len(model.names)):
        if model.roles[j] == FIXED:
            continue
        path, k = float(np.linalg.norm(tails[j] - heads[j])), j
        while k != model.root:
            p = model.parents[k]
            path += float(np.linalg.norm(heads[k] - heads[p]))
            k = p
        best = max(best, path)
    return best


def _cube(centre, half):
    return np.asarray(centre, dtype=np.float64) + half * np.array(
        [[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=np.float64)


def test_the_skeletons_reach_is_its_longest_path_from_the_root(rig):
    model, h, t, _x = rig
    stretched = h * np.array([1.0, 1.3, 0.8])  # another pose of other proportions on a second frame
    reach = skeleton_reach(model, np.stack([h, stretched]), np.stack([t, t * np.array([1.0, 1.3, 0.8])]))
    np.testing.assert_allclose(reach, [_walked_reach(model, h, t),
                                       _walked_reach(model, stretched, t * np.array([1.0, 1.3, 0.8]))], rtol=1e-12)
    assert reach[0] < np.ptp(np.concatenate([h, t]), axis=0).max() * 2.0  # a body's length, not more


offsets = arrays(np.float64, (2, 3), elements=st.floats(-3.0, 3.0))


@settings(deadline=None, max_examples=15)
@given(kind=st.sampled_from(metarig.CASES), hand_offsets=offsets)
def test_every_solved_bone_stays_inside_the_reach_ball(rig, kind, hand_offsets):
    """Hands anywhere up to three body heights off (far beyond reach too), feet planted."""
    model, h, t, x = rig
    targets, boxes = metarig.case(model, h, t, kind)
    height = float(np.ptp(np.concatenate([h, t])[:, 2]))
    targets[:2] += hand_offsets * height
    res = adjust_pose(model, h, t, targets, metarig.EFFECTORS, metarig.PRIORITIES, obstacles=boxes, bone_x_axes=x)
    centre, radius = body_reach(model, h[None], t[None], targets[None])
    farthest = max(np.linalg.norm(res.heads - centre[0], axis=1).max(), np.linalg.norm(res.tails - centre[0], axis=1).max())
    assert farthest <= radius[0]


def test_boxes_out_of_reach_are_left_out_and_the_others_kept_in_order():
    centre, radius = np.zeros((2, 3)), np.array([1.0, 1.0])
    near = _cube([0.5, 0.0, 0.0], 0.1)
    touching = _cube([1.05, 0.0, 0.0], 0.1)  # its face at 0.95: inside the ball
    far = _cube([5.0, 0.0, 0.0], 0.1)
    shared = Boxes.from_box_corners(np.stack([far, near, far, touching]))
    kept = reachable_boxes(shared, centre, radius)
    np.testing.assert_array_equal(kept.mins, shared.mins[[1, 3]])
    assert reachable_boxes(Boxes.from_box_corners(np.stack([near, touching])), centre, radius) is not None
    assert reachable_boxes(Boxes.from_box_corners(far[None]), centre, radius) is None
    both = Boxes.from_box_corners(np.stack([near, touching]))
    assert reachable_boxes(both, centre, radius) is both
    # Per frame: a box near on one frame is kept on every frame; one far on all frames goes.
    per_frame = Boxes.from_box_corners(np.stack([np.stack([far, far]), np.stack([near, far])]))
    kept = reachable_boxes(per_frame, centre, radius)
    assert kept.mins.shape == (2, 1, 3)
    np.testing.assert_array_equal(kept.mins, per_frame.mins[:, :1])


@pytest.mark.parametrize("kind", metarig.CASES)
def test_far_boxes_change_nothing(rig, kind):
    """A solve with a hundred boxes far from the body added is the solve without them, bit for bit, alone and in
    a batch (shared and per-frame boxes)."""
    model, h, t, x = rig
    targets, boxes = metarig.case(model, h, t, kind)
    height = float(np.ptp(np.concatenate([h, t])[:, 2]))
    far = np.stack([_cube(h[model.root] + height * np.array([40.0 + 3 * k, 30.0, 0.0]), 0.2 * height)
                    for k in range(100)])
    far = Boxes.from_corners(far)
    assert boxes is None or boxes.axes is None  # the case's box is axis-aligned, as the far ones
    mins = [far.mins[:50]] + ([] if boxes is None else [boxes.mins]) + [far.mins[50:]]
    maxs = [far.maxs[:50]] + ([] if boxes is None else [boxes.maxs]) + [far.maxs[50:]]
    crowded = Boxes(np.concatenate(mins), np.concatenate(maxs))
    args = (model, h, t, targets, metarig.EFFECTORS, metarig.PRIORITIES)
    alone = adjust_pose(*args, obstacles=boxes, bone_x_axes=x)
    among = adjust_pose(*args, obstacles=crowded, bone_x_axes=x)
    for field in ("heads", "tails", "rotations", "residuals"):
        np.testing.assert_array_equal(getattr(among, field), getattr(alone, field))
    assert list(among.status) == list(alone.status) and list(among.reasons) == list(alone.reasons)

    n = 3
    frames = (np.repeat(h[None], n, 0), np.repeat(t[None], n, 0), np.repeat(targets[None], n, 0))
    per_frame = Boxes(np.repeat(crowded.mins[None], n, 0), np.repeat(crowded.maxs[None], n, 0))
    batch_alone = adjust_frames(model, *frames, metarig.EFFECTORS, metarig.PRIORITIES, obstacles=boxes,
                                bone_x_axes=np.repeat(x[None], n, 0))
    batch_among = adjust_frames(model, *frames, metarig.EFFECTORS, metarig.PRIORITIES, obstacles=per_frame,
                                bone_x_axes=np.repeat(x[None], n, 0))
    np.testing.assert_array_equal(batch_among.heads, batch_alone.heads)
    np.testing.assert_array_equal(batch_among.residuals, batch_alone.residuals)
