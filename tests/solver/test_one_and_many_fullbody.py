"""The full-body adjustment written once (fullbody/limb_placement.py's top-down pass, fullbody/outcome.py's effector
status): F frames solved together against each frame solved alone (as Adjust Pose and Live solve it), every result
field bit for bit, on captured-style metarig problems (boxes, poles, wanted hand and foot orientations) and on random
ones (tests/helpers/random_bodies.py: any scale, targets at the root, at a limb's base, coincident, far); and the
effector status kernel on every branch it has, for many frames at once and each alone."""

import numpy as np
import pytest

from fullbody_adjust.solver.fullbody.adjust import AdjustSettings, adjust_frames
from fullbody_adjust.solver.fullbody.limb_rotations import LimbSolve
from fullbody_adjust.solver.fullbody.outcome import effector_outcome
from fullbody_adjust.solver.fullbody.settings import UNCONSTRAINED
from fullbody_adjust.solver.maths import lanes
from fullbody_adjust.solver.obstacles.boxes import Boxes
from tests.helpers import metarig, random_bodies
from tests.solver.test_stacked_limbs import FIELDS, _four_limbs_case

MANY = lanes.FEW + 3  # more frames than lanes solves one at a time


@pytest.fixture(scope="module")
def rig():
    return metarig.load()


def _bits(a):
    return np.ascontiguousarray(a, dtype=np.float64).view(np.int64)


def _same_as_alone(args, kwargs, per_frame=("bone_x_axes", "poles", "end_turns")):
    """adjust_frames on all frames of `args` against each frame alone: every field of every frame, bit for bit.
    Returns the batch's result."""
    model, heads, tails, targets, effectors, priorities = args
    together = adjust_frames(*args, **kwargs)
    boxes = kwargs.get("obstacles")
    for f in range(len(targets)):
        one = dict(kwargs)
        for name in per_frame:
            if one.get(name) is not None:
                one[name] = one[name][f:f + 1]
        if boxes is not None and boxes.batched:
            one["obstacles"] = Boxes(boxes.mins[f:f + 1], boxes.maxs[f:f + 1])
        alone = adjust_frames(model, heads[f:f + 1], tails[f:f + 1], targets[f:f + 1], effectors, priorities, **one)
        for field in FIELDS:
            a, b = np.asarray(getattr(alone, field))[0], np.asarray(getattr(together, field))[f]
            if a.dtype.kind == "f":
                np.testing.assert_array_equal(_bits(a), _bits(b), err_msg=f"frame {f}: {field}")
            else:
                assert a.tolist() == b.tolist(), f"frame {f}: {field}"
    return together


def _turns(rng, n):
    """Wanted world rotation deltas (n,E,3,3) of the hands and feet, NaN (none) for about a third of them."""
    turns = random_bodies.rotations(rng, n * len(metarig.EFFECTORS), np.full(n * len(metarig.EFFECTORS), np.pi))
    turns = turns.reshape(n, len(metarig.EFFECTORS), 3, 3)
    turns[rng.random((n, len(metarig.EFFECTORS))) < 0.3] = np.nan
    turns[:, -1] = np.nan  # the head takes no end turn
    return turns


@pytest.mark.parametrize("per_frame_boxes", [False, True])
@pytest.mark.parametrize("with_turns", [False, True])
def test_metarig_frames_together_and_alone(rig, per_frame_boxes, with_turns):
    """tests/solver/test_stacked_limbs.py's four frames (a box in the way, a hand beyond reach, a foot held short by
    its limits, a hand at its start, poles) twice, the second time jittered: MANY frames or more, solved together on
    arrays and each alone on floats."""
    model, heads, tails, targets, boxes, x, poles = _four_limbs_case(rig, per_frame_boxes)
    rng = np.random.default_rng(3)
    height = float(np.ptp(heads[0, :, 2]))
    twice = (lambda a: np.concatenate([a, a]))  # noqa: E731
    heads, tails, x, poles = twice(heads), twice(tails), twice(x), twice(poles)
    targets = twice(targets)
    targets[4:] += rng.normal(scale=0.01 * height, size=targets[4:].shape)
    if per_frame_boxes:
        boxes = Boxes(twice(boxes.mins), twice(boxes.maxs))
    assert len(targets) >= MANY - 1 > lanes.FEW
    turns = _turns(rng, len(targets)) if with_turns else None
    result = _same_as_alone((model, heads, tails, targets, metarig.EFFECTORS, metarig.PRIORITIES),
                            dict(obstacles=boxes, bone_x_axes=x, poles=poles, end_turns=turns))
    statuses = set(result.status.ravel().tolist())
    assert {"reached", "unreachable"} <= statuses and (result.heads != heads).any()


@pytest.mark.parametrize("seed", range(8))
def test_random_bodies_together_and_alone(rig, seed):
    """Random problems (random_bodies.batch: start poses, scale, target kinds, boxes) with random priorities and
    variant; MANY frames together against each alone."""
    rng = np.random.default_rng([28, seed])
    b = random_bodies.batch(rng, rig, MANY, jitter=10.0 ** rng.uniform(-6.0, -2.0))
    settings = AdjustSettings(variant=str(rng.choice(["priority", "weighted", "fabrik"])))
    priorities = rng.choice([0.0, 1.0, 2.0, 3.0], len(metarig.EFFECTORS))
    _same_as_alone((rig[0], b.heads, b.tails, b.targets, metarig.EFFECTORS, priorities),
                   dict(obstacles=b.obstacles, bone_x_axes=b.x_axes, settings=settings))


def _outcome_case(rng, frames):
    """A synthetic outcome: a two-effector model's limb ends, targets (some met, some missed, none on some frames)
    and chain statuses covering every branch: met with and without a reason, missed after a 'reached' chain (moved
    off), an unreachable arm whose trunk was blocked or limited (or not solved, or reached)."""
    model = metarig.load()[0]
    effectors = ("hand.L", "foot.L")
    J = len(model.names)
    heads, tails = rng.normal(size=(frames, J, 3)), rng.normal(size=(frames, J, 3))
    ends = np.stack([model.limbs[n].end_point(heads, tails) for n in ("arm.L", "leg.L")], axis=1)
    tol = 1e-6
    miss = rng.choice([0.0, 0.5 * tol, 2.0 * tol, 0.3], size=(frames, 2))
    direction = rng.normal(size=(frames, 2, 3))
    direction /= np.linalg.norm(direction, axis=2, keepdims=True)
    targets = ends + direction * miss[..., None]
    active = rng.random((frames, 2)) < 0.8
    targets[~active] = np.nan
    statuses = np.array(["reached", "unreachable", "blocked", "limited", "max_iterations"], dtype=object)
    reasons = np.array(["", "why not", "reached in 3 iterations"], dtype=object)
    solves = {}
    for name in ("arm.L", "leg.L", "trunk"):
        solves[name] = LimbSolve(None, rng.random(frames) < 0.8, statuses[rng.integers(0, 5, frames)],
                                 reasons[rng.integers(0, 3, frames)] + (" " + name))
    return model, effectors, targets, active, tol, heads, tails, solves


def _expected(solves, name, on_sc, res, active, tol, f):
    """One effector's (status, reason) from the rules, as effector_outcome documents them."""
    if not active:
        return UNCONSTRAINED, "no target on this frame"
    st, why = solves[name].status[f], solves[name].reason[f]
    if res <= tol:
        return "reached", why or "reached"
    if st == "reached":
        st, why = "unreachable", "moved off its target after the chain solve"
    trunk = solves["trunk"]
    if st == "unreachable" and on_sc and trunk.solved[f] and trunk.status[f] in ("blocked", "limited"):
        st, why = trunk.status[f], "the trunk could not bring the SC into reach: " + trunk.reason[f]
    return st, why


@pytest.mark.parametrize("frames", [1, MANY, 300])
def test_effector_outcome_together_and_alone(frames):
    rng = np.random.default_rng(frames)
    case = _outcome_case(rng, frames)
    model, effectors, targets, active, tol, heads, tails, solves = case
    residuals, status, reasons = effector_outcome(*case)
    branches = set()
    for f in range(frames):
        one = slice(f, f + 1)
        part = {n: LimbSolve(None, s.solved[one], s.status[one], s.reason[one]) for n, s in solves.items()}
        r1, s1, w1 = effector_outcome(model, effectors, targets[one], active[one], tol, heads[one], tails[one], part)
        np.testing.assert_array_equal(_bits(r1[0]), _bits(residuals[f]), err_msg=f"frame {f}")
        assert s1[0].tolist() == status[f].tolist() and w1[0].tolist() == reasons[f].tolist()
        for k, name in enumerate(("arm.L", "leg.L")):
            end = model.limbs[name].end_point(heads[f], tails[f])
            res = float(np.sqrt(np.sum((end - targets[f, k]) ** 2))) if active[f, k] else np.nan
            st, why = _expected(solves, name, name == "arm.L", res, active[f, k], tol, f)
            assert (status[f, k], reasons[f, k]) == (st, why), f"frame {f}, {name}"
            assert np.isnan(residuals[f, k]) if not active[f, k] else abs(residuals[f, k] - res) <= 1e-12
            branches.add(why.split(":")[0] if "trunk" in why or "moved off" in why else st)
    if frames == 300:  # every branch met: the trunk's statuses, moved off, met, unconstrained
        assert {"reached", UNCONSTRAINED, "moved off its target after the chain solve",
                "the trunk could not bring the SC into reach"} <= branches
