"""Sibling limbs (left and right arms, left and right legs) go through one stacked chain solve and one stacked
computation of their segment rotations: the results must be exactly those of solving each limb alone, and limbs
whose limits differ must not be stacked."""

import numpy as np
import pytest

from fullbody_adjust.solver.fullbody import limb_placement
from fullbody_adjust.solver.fullbody.adjust import adjust_frames
from fullbody_adjust.solver.limits.human import LimbLimits, default_limits
from fullbody_adjust.solver.limits.joint_limits import HINGE
from fullbody_adjust.solver.obstacles.boxes import Boxes
from tests.helpers import metarig

FIELDS = ("heads", "tails", "rotations", "residuals", "status", "reasons", "iterations",
          "sc_displacement", "root_displacement")


@pytest.fixture(scope="module")
def rig():
    return metarig.load()


def _four_limbs_case(rig, per_frame_boxes):
    """Four frames where both feet move (each frame differently) and both hands: on frame 0 to metarig's
    obstacle case (its box where the left forearm would go), on frame 1 the left hand beyond reach, on frames
    2 and 3 elsewhere (on frame 2 the left foot raised to where its limits hold the leg short, which also runs
    the re-solve of held limbs); on frame 3 the right hand at its start. Poles for the left elbow on frame 2
    and the right knee on frame 0 only: stacked with limbs without one."""
    model, h, t, x = rig
    base, boxes = metarig.case(model, h, t, "obstacle")
    far, _ = metarig.case(model, h, t, "far")
    height = float(np.ptp(np.concatenate([h, t])[:, 2]))
    rng = np.random.default_rng(7)
    targets = np.repeat(base[None], 4, 0)
    targets[1, 0] = far[0]
    targets[2:, :2] += rng.normal(scale=0.08, size=(2, 2, 3)) * height
    targets[:, 2] += np.array([0.02, -0.04, 0.07]) * height + rng.normal(scale=0.01, size=(4, 3)) * height
    targets[:, 3] += np.array([-0.03, 0.05, 0.05]) * height + rng.normal(scale=0.01, size=(4, 3)) * height
    targets[3, 1] = metarig.wrists_and_ankles(model, h)[1]
    targets[2, 2] += np.array([0.0, -0.3, 0.3]) * height
    if per_frame_boxes:  # one box per frame, drifting: the stacked rows must pick their own frame's box
        shift = np.linspace(0.0, 0.01, 4)[:, None, None] * height
        boxes = Boxes(boxes.mins[None] + shift, boxes.maxs[None] + shift)
    poles = np.full(targets.shape, np.nan)
    poles[2, 0] = targets[2, 0] + np.array([0.1, 0.2, -0.3]) * height
    poles[0, 3] = targets[0, 3] + np.array([0.0, -0.3, 0.3]) * height
    n = len(targets)
    return model, np.repeat(h[None], n, 0), np.repeat(t[None], n, 0), targets, boxes, np.repeat(x[None], n, 0), \
        poles


def _solve(case, limits=None):
    model, heads, tails, targets, boxes, x, poles = case
    return adjust_frames(model, heads, tails, targets, metarig.EFFECTORS, metarig.PRIORITIES, obstacles=boxes,
                         bone_x_axes=x, limits=limits, poles=poles)


def _solve_recording_groups(monkeypatch, case, limits=None):
    """The solve, and the limbs of every stacked group it ran (groups of one left out)."""
    stacked = []
    group = limb_placement._group_limbs

    def recording(tasks, key):
        groups = group(tasks, key)
        stacked.extend(tuple(t.name for t in g) for g in groups if len(g) > 1)
        return groups

    with monkeypatch.context() as patch:
        patch.setattr(limb_placement, "_group_limbs", recording)
        return _solve(case, limits), stacked


def _solve_one_limb_at_a_time(monkeypatch, case, limits=None):
    with monkeypatch.context() as patch:
        patch.setattr(limb_placement, "_group_limbs", lambda tasks, key: [[t] for t in tasks])
        return _solve(case, limits)


def _assert_identical(stacked, alone):
    for name in FIELDS:
        a, b = getattr(stacked, name), getattr(alone, name)
        same = np.array_equal(a, b, equal_nan=True) if a.dtype.kind == "f" else np.array_equal(a, b)
        assert same, f"{name} differs between the stacked and the one-limb-at-a-time solve"


@pytest.mark.parametrize("per_frame_boxes", [False, True])
def test_stacked_arms_and_legs_equal_each_limb_solved_alone(rig, monkeypatch, per_frame_boxes):
    case = _four_limbs_case(rig, per_frame_boxes)
    stacked, groups = _solve_recording_groups(monkeypatch, case)
    assert ("arm.L", "arm.R") in groups and ("leg.L", "leg.R") in groups
    alone = _solve_one_limb_at_a_time(monkeypatch, case)
    # The case exercises what it claims: every limb moved; targets reached, out of reach, held by limits.
    model, heads, tails = case[:3]
    assert all((stacked.heads[:, model.groups[g]] != heads[:, model.groups[g]]).any()
               for g in ("arm.L", "arm.R", "leg.L", "leg.R"))
    assert {"reached", "unreachable", "limited"} <= set(stacked.status[:, :4].ravel())
    _assert_identical(stacked, alone)


def test_arms_with_different_limits_are_solved_apart(rig, monkeypatch):
    case = _four_limbs_case(rig, per_frame_boxes=False)
    model, heads, tails, _, _, x, _ = case
    limits = default_limits(model, heads, tails, bone_x_axes=x)
    right = limits["arm.R"]
    narrower = right.limits.with_cone(0, float(right.limits.cone_angle[0]) * 0.5)
    limits["arm.R"] = LimbLimits(narrower, right.parent_direction)
    assert limits["arm.L"].limits.cone_angle[0] != narrower.cone_angle[0]
    stacked, groups = _solve_recording_groups(monkeypatch, case, limits)
    assert ("arm.L", "arm.R") not in groups and ("leg.L", "leg.R") in groups
    _assert_identical(stacked, _solve_one_limb_at_a_time(monkeypatch, case, limits))


def _mixed_frames_case(rig):
    """The four frames of _four_limbs_case and two more where sibling limbs are solved on different frames:
    on frame 4 the left hand has no target and the left foot stays at its start (neither limb solved there),
    on frame 5 the right hand stays at its start and the right foot has no target; the other hand and foot
    move within reach."""
    model, heads, tails, targets, boxes, x, poles = _four_limbs_case(rig, per_frame_boxes=False)
    h, t = heads[0], tails[0]
    height = float(np.ptp(np.concatenate([h, t])[:, 2]))
    start = metarig.wrists_and_ankles(model, h)
    near, _ = metarig.case(model, h, t, "near")
    extra = np.repeat(start[None], 2, 0)
    extra[0, 0], extra[0, 1] = np.nan, near[1]
    extra[0, 3] += np.array([0.01, 0.02, 0.03]) * height
    extra[1, 0] = near[0]
    extra[1, 2] += np.array([-0.02, 0.01, 0.03]) * height
    extra[1, 3] = np.nan
    grow = lambda a: np.concatenate([a, a[:2]])  # noqa: E731  (the start poses of two more frames)
    return model, grow(heads), grow(tails), np.concatenate([targets, extra]), boxes, grow(x), \
        np.concatenate([poles, np.full_like(extra, np.nan)])


def test_stacked_segment_rotations_equal_each_limb_alone(rig, monkeypatch):
    """Sibling limbs also get their segment rotations from one stacked call, on their own solved frames (which
    differ between them here), hinges included: every result field equals that of one limb at a time."""
    case = _mixed_frames_case(rig)
    calls = []
    compute = limb_placement.set_segment_rotations

    def recording(solves, starts, limits):
        calls.append(([ls.solved.copy() for ls in solves], limits))
        return compute(solves, starts, limits)

    with monkeypatch.context() as patch:
        patch.setattr(limb_placement, "set_segment_rotations", recording)
        stacked = _solve(case)
    stacked_calls = [(solved, limits) for solved, limits in calls if len(solved) > 1]
    hinged = [solved for solved, limits in stacked_calls
              if limits[0] is not None and np.any(limits[0].limits.kind[1:] == HINGE)]
    # Arms and legs (both hinged at the elbow or knee) each in one call, solved on some frames and not others,
    # with different frames for the two sides.
    assert len(hinged) >= 2
    assert any(all(s.any() and not s.all() for s in solved) and not np.array_equal(*solved) for solved in hinged)
    _assert_identical(stacked, _solve_one_limb_at_a_time(monkeypatch, case))
