"""solver.rig_limits: a rig's own IK locks and ranges replace the default limits of the joints they are set on.

The rig is the synthetic humanoid of test_adjust.py with Blender-like bone axes (Y along the bone, the elbow's
and knee's X axis their bend axis); its start pose is its rest pose. Every angle is measured here from the
solved heads and rotations, the way Blender reads a bone's rotation: relative to its rest orientation in its
parent's frame.
"""

import math
from dataclasses import replace

import numpy as np
import pytest

from fullbody_adjust.solver.fullbody import adjust
from fullbody_adjust.solver.fullbody.adjust import adjust_frames
from fullbody_adjust.solver.fullbody.settings import AdjustSettings
from fullbody_adjust.solver.limits.human import default_limits
from fullbody_adjust.solver.errors import SolverInputError
from fullbody_adjust.solver.limits.joint_limits import HINGE
from fullbody_adjust.solver.limits.rig_limits import BoneLimitSpec, rig_limits

from .test_adjust import EFFECTORS, _descendants, synthetic_humanoid

FLOAT = 1e-9


def _unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def bone_axes(model, heads, tails):
    """(F,J,3,3) bone axes as columns: Y along the bone; X the bend axis of arms and legs (upper x lower bone,
    so an elbow and a knee bend about X as in Blender rigs), else world X made perpendicular to Y."""
    y = _unit(tails - heads)
    x_ref = np.broadcast_to([1.0, 0.0, 0.0], y.shape).copy()
    for limb in ("arm.L", "arm.R", "leg.L", "leg.R"):
        upper, lower = model.limbs[limb].bones[-2:]
        bend = _unit(np.cross(y[:, upper], y[:, lower]))
        x_ref[:, upper] = x_ref[:, lower] = bend
    x = _unit(x_ref - np.sum(x_ref * y, axis=-1, keepdims=True) * y)
    return np.stack([x, y, np.cross(x, y)], axis=-1)


@pytest.fixture(scope="module")
def body():
    model, heads, tails = synthetic_humanoid()
    return model, heads, tails, bone_axes(model, heads, tails)


def spec(model, axes, bone, locked=(False, False, False), ranges=(None, None, None)):
    """A spec for `bone` whose rest is the start pose (frame 0)."""
    j = model.names.index(bone)
    p = model.parents[j]
    return {bone: BoneLimitSpec(locked, ranges, axes[0, p].T @ axes[0, j])}


def solve(model, heads, tails, axes, targets, specs=None):
    limits = default_limits(model, heads, tails, bone_x_axes=axes[..., 0])
    if specs is not None:
        limits = rig_limits(limits, model, heads, tails, axes, specs)
    return adjust_frames(model, heads, tails, targets, EFFECTORS, limits=limits)


def hand_targets(goals):
    """(F,4,3): the left hand's target per frame, the other effectors free (NaN)."""
    out = np.full((len(goals), len(EFFECTORS), 3), np.nan)
    out[:, 0] = goals
    return out


def frames(heads, tails, n):
    return np.repeat(heads, n, axis=0), np.repeat(tails, n, axis=0)


def local_direction(model, axes0, res, bone):
    """(F,3) the bone's direction in its rest frame carried by its parent's solved pose (rest = start)."""
    j = model.names.index(bone)
    p = model.parents[j]
    parent_now = res.rotations[:, p] @ axes0[:, p]
    rest_frame = parent_now @ (np.swapaxes(axes0[:, p], -1, -2) @ axes0[:, j])
    d = _unit(res.tails[:, j] - res.heads[:, j])
    return np.einsum("fji,fj->fi", rest_frame, d)


def x_rotation(d):
    """Rotation about X (radians) of local directions d (F,3) from the rest direction +Y."""
    return np.arctan2(d[:, 2], d[:, 1])


def elbow_angle(model, heads, tails):
    j = model.limbs["arm.L"].joints(heads, tails)
    u, v = j[:, 2] - j[:, 1], j[:, 3] - j[:, 2]
    return np.arctan2(np.linalg.norm(np.cross(u, v), axis=-1), np.sum(u * v, axis=-1))


def pulling_goals(model, heads, tails, n=6):
    """Left-hand goals around the shoulder, within the arm's reach but off the start bend: the elbow must bend
    (or unbend, or swing) to reach most of them."""
    arm = model.limbs["arm.L"].joints(heads, tails)[0]
    shoulder, wrist = arm[1], arm[3]
    reach = np.linalg.norm(np.diff(arm[1:], axis=0), axis=1).sum()
    angles = np.linspace(0.0, 2 * math.pi, n, endpoint=False)
    goals = [shoulder + reach * np.array([0.3 * math.cos(a), -0.6 + 0.3 * math.sin(a), -0.2]) for a in angles]
    goals += [wrist + np.array([0.0, -0.15, 0.15]), shoulder + np.array([0.05, -0.5 * reach, -0.2 * reach])]
    return np.array(goals)


def pulled(model, h0, t0, a0):
    """One frame per pulling goal: start heads, tails, bone axes (F,J,...) and the left hand's targets."""
    goals = pulling_goals(model, h0, t0)
    heads, tails = frames(h0, t0, len(goals))
    return heads, tails, np.repeat(a0, len(goals), axis=0), hand_targets(goals)


def test_x_and_z_locked_hold_the_elbow(body):
    model, h0, t0, a0 = body
    heads, tails, axes, targets = pulled(model, h0, t0, a0)
    start = elbow_angle(model, heads, tails)
    free = solve(model, heads, tails, axes, targets)
    assert np.max(np.abs(elbow_angle(model, free.heads, free.tails) - start)) > 0.3  # the targets need a bend
    locked = solve(model, heads, tails, axes, targets, spec(model, a0, "forearm.L", locked=(True, False, True)))
    np.testing.assert_allclose(elbow_angle(model, locked.heads, locked.tails), start, atol=1e-7)
    # Held relative to the upper arm too (not only the angle): the forearm keeps its rest direction.
    np.testing.assert_allclose(local_direction(model, axes, locked, "forearm.L"),
                               np.broadcast_to([0.0, 1.0, 0.0], (len(targets), 3)), atol=1e-7)


def test_a_limit_pass_not_taken_is_not_run_again(body, monkeypatch):
    """With the elbow locked the left hand falls short of most pulling goals. The first limit pass solves those
    frames again with the arm's reach cut to what it achieved; where that re-solve is not taken, a further pass
    would start from the same result with the same cut reach and give the same pose, not taken again: such a
    frame has no further pass. Five passes cost what one does and give the same poses."""
    model, h0, t0, a0 = body
    heads, tails, axes, targets = pulled(model, h0, t0, a0)
    limits = rig_limits(default_limits(model, heads, tails, bone_x_axes=axes[..., 0]), model, heads, tails, axes,
                        spec(model, a0, "forearm.L", locked=(True, False, True)))
    solved_frames = []
    solve_once = adjust._Problem._solve_once

    def counted(problem):
        solved_frames.append(problem.F)
        return solve_once(problem)

    monkeypatch.setattr(adjust._Problem, "_solve_once", counted)
    runs = {}
    for passes in (0, 1, 5):
        solved_frames.clear()
        result = adjust_frames(model, heads, tails, targets, EFFECTORS, limits=limits,
                               settings=replace(AdjustSettings(), limit_passes=passes))
        runs[passes] = (result, list(solved_frames))
    held = int(np.sum(runs[0][0].status[:, 0] == "limited"))
    assert held >= 3 and runs[1][1] == [len(targets), held]  # the first pass re-solves every held frame
    for field in ("heads", "tails", "rotations", "residuals", "status"):
        # ... and takes none of them here, so a second would only repeat it
        np.testing.assert_array_equal(getattr(runs[1][0], field), getattr(runs[0][0], field))
        np.testing.assert_array_equal(getattr(runs[5][0], field), getattr(runs[1][0], field))
    assert runs[5][1] == runs[1][1]


def rolled(model, axes, bone, angle):
    """`axes` with `bone`'s X and Z turned about its Y by `angle` (a roll: its X axis no longer the bend axis,
    not perpendicular to the parent bone any more)."""
    out = axes.copy()
    j = model.names.index(bone)
    c, s = math.cos(angle), math.sin(angle)
    out[:, j] = axes[:, j] @ np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])
    return out


@pytest.mark.parametrize("roll", [0.0, 0.1])
def test_x_range_holds_while_the_targets_pull_outside(body, roll):
    model, h0, t0, a0 = body
    a0 = rolled(model, a0, "forearm.L", roll)
    heads, tails, axes, targets = pulled(model, h0, t0, a0)
    lo, hi = -0.1, 0.35
    free = solve(model, heads, tails, axes, targets)
    wanted = x_rotation(local_direction(model, axes, free, "forearm.L"))
    assert wanted.min() < lo - 0.1 or wanted.max() > hi + 0.1  # without the range the elbow leaves it
    ranged = solve(model, heads, tails, axes, targets, spec(model, a0, "forearm.L", ranges=((lo, hi), None, None)))
    d = local_direction(model, axes, ranged, "forearm.L")
    x = x_rotation(d)
    assert np.all(x >= lo - 1e-7) and np.all(x <= hi + 1e-7)
    assert x.max() > hi - 1e-6 and np.ptp(x) > 0.03  # pulled to the bound, and bending inside the range
    if roll == 0.0:  # Z (the free axis) held at rest: conservative (rolled, the plane must hold the parent)
        np.testing.assert_allclose(d[:, 0], 0.0, atol=1e-7)


def test_z_locked_leaves_a_free_hinge_about_x(body):
    model, h0, t0, a0 = body
    heads, tails, axes, targets = pulled(model, h0, t0, a0)
    specs = spec(model, a0, "forearm.L", locked=(False, False, True))
    lim = rig_limits(default_limits(model, heads, tails, bone_x_axes=axes[..., 0]), model, heads, tails, axes,
                     specs)["arm.L"].limits
    assert (lim.hinge_min[2], lim.hinge_max[2]) == (-math.pi, math.pi)  # no range on X: the whole circle
    res = solve(model, heads, tails, axes, targets, specs)
    d = local_direction(model, axes, res, "forearm.L")
    np.testing.assert_allclose(d[:, 0], 0.0, atol=1e-7)  # no turn about Z
    assert np.ptp(x_rotation(d)) > 0.5  # while it bends about X


def test_ranges_map_to_hinge_bounds_shifted_by_the_rest_bend(body):
    model, heads, tails, axes = body
    defaults = default_limits(model, heads, tails, bone_x_axes=axes[..., 0])
    lo, hi = -0.4, 0.9
    out = rig_limits(defaults, model, heads, tails, axes, spec(model, axes, "shin.L", ranges=((lo, hi), None, None)))
    knee = out["leg.L"].limits
    leg = model.limbs["leg.L"].joints(heads, tails)[0]
    thigh, shin = _unit(leg[1] - leg[0]), _unit(leg[2] - leg[1])
    x = axes[0, model.names.index("shin.L"), :, 0]
    rest_bend = math.atan2(np.dot(np.cross(x, thigh), shin), np.dot(thigh, shin))  # about X, from the thigh
    assert knee.kind[1] == HINGE and knee.hinge_twist[1] == 0.0
    assert knee.hinge_min[1] == pytest.approx(rest_bend + lo, abs=FLOAT)
    assert knee.hinge_max[1] == pytest.approx(rest_bend + hi, abs=FLOAT)
    np.testing.assert_allclose(knee.hinge_axis[0, 1], x, atol=FLOAT)
    # Everything else is the defaults, untouched.
    assert out["leg.R"] is defaults["leg.R"] and out["arm.L"] is defaults["arm.L"]
    np.testing.assert_array_equal(knee.kind[0], defaults["leg.L"].limits.kind[0])


def test_joint_0_is_measured_from_the_rest_direction(body):
    model, h0, t0, a0 = body
    n = 6
    heads, tails = frames(h0, t0, n)
    axes = np.repeat(a0, n, axis=0)
    leg = model.limbs["leg.L"].joints(h0, t0)[0]
    reach = np.linalg.norm(np.diff(leg, axis=0), axis=1).sum()
    swing = np.linspace(-1.0, 1.0, n)
    goals = leg[0] + 0.9 * reach * np.stack([0.3 * swing, -np.sin(swing), -np.cos(swing)], axis=1)
    targets = np.full((n, len(EFFECTORS), 3), np.nan)
    targets[:, 2] = goals
    lo, hi = -0.25, 0.2
    free = adjust_frames(model, heads, tails, targets, EFFECTORS, limits=default_limits(model, heads, tails))
    wanted = x_rotation(local_direction(model, axes, free, "thigh.L"))
    assert wanted.min() < lo - 0.1 and wanted.max() > hi + 0.1  # the goals need more than the range
    limits = rig_limits(default_limits(model, heads, tails, bone_x_axes=axes[..., 0]), model, heads, tails, axes,
                        spec(model, a0, "thigh.L", ranges=((lo, hi), None, None)))
    res = adjust_frames(model, heads, tails, targets, EFFECTORS, limits=limits)
    x = x_rotation(local_direction(model, axes, res, "thigh.L"))
    assert np.all(x >= lo - 1e-7) and np.all(x <= hi + 1e-7)
    assert x.min() < lo + 1e-3 and x.max() > hi - 1e-3  # the goals pull against both bounds


def test_lock_over_frames_with_different_start_bends_spans_them(body):
    model, h0, t0, a0 = body
    heads, tails = frames(h0, t0, 2)
    # Frame 1: the forearm bent a further 0.3 rad about its X axis (the hand and fingers follow).
    fore = model.names.index("forearm.L")
    x = a0[0, fore, :, 0]
    c, s = math.cos(0.3), math.sin(0.3)
    cross_x = np.array([[0, -x[2], x[1]], [x[2], 0, -x[0]], [-x[1], x[0], 0]])
    turn = c * np.eye(3) + s * cross_x + (1 - c) * np.outer(x, x)
    pivot = heads[1, fore].copy()
    moved = sorted(_descendants(model, [fore]))
    heads[1, moved] = pivot + (heads[1, moved] - pivot) @ turn.T
    tails[1, moved] = pivot + (tails[1, moved] - pivot) @ turn.T
    axes = np.repeat(a0, 2, axis=0)
    defaults = default_limits(model, heads, tails, bone_x_axes=axes[..., 0])
    out = rig_limits(defaults, model, heads, tails, axes, spec(model, a0, "forearm.L", locked=(True, False, True)))
    lim = out["arm.L"].limits
    start = elbow_angle(model, heads, tails)
    assert lim.kind[2] == HINGE
    assert (lim.hinge_min[2], lim.hinge_max[2]) == pytest.approx((start.min(), start.max()), abs=FLOAT)


def test_neither_range_holding_the_rest_holds_the_corner(body):
    model, h0, t0, a0 = body
    heads, tails = frames(h0, t0, 3)
    axes = np.repeat(a0, 3, axis=0)
    targets = hand_targets(pulling_goals(model, h0, t0)[:3])
    res = solve(model, heads, tails, axes, targets,
                spec(model, a0, "forearm.L", ranges=((0.2, 0.5), None, (-0.4, -0.1))))
    d = local_direction(model, axes, res, "forearm.L")
    # Euler XYZ (X first, then Z) of the held direction: X = 0.2, Z = -0.1, the corner nearest the rest.
    cx, sx, cz, sz = math.cos(0.2), math.sin(0.2), math.cos(-0.1), math.sin(-0.1)
    expected = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]]) @ np.array([0.0, cx, sx])
    np.testing.assert_allclose(d, np.broadcast_to(expected, d.shape), atol=1e-7)


def test_twist_only_and_no_specs_change_nothing(body):
    model, heads, tails, axes = body
    defaults = default_limits(model, heads, tails, bone_x_axes=axes[..., 0])
    twist_only = {**spec(model, axes, "forearm.L", locked=(False, True, False)),
                  **spec(model, axes, "shin.R", ranges=(None, (-0.1, 0.1), None)),
                  **spec(model, axes, "hand.L", locked=(True, True, True))}  # not a chain joint: ignored
    for specs in ({}, twist_only):
        out = rig_limits(defaults, model, heads, tails, axes, specs)
        assert out.keys() == defaults.keys() and all(out[k] is defaults[k] for k in out)


@pytest.mark.parametrize("make, message", [
    (lambda: BoneLimitSpec(ranges=((0.5, 0.1), None, None)), "X range is empty"),
    (lambda: BoneLimitSpec(ranges=(None, None, (0.0, math.inf))), "Z range has NaN/inf"),
    (lambda: BoneLimitSpec(rest_in_parent=np.eye(2)), "3x3"),
    (lambda: BoneLimitSpec(locked=(True, True)), "per axis"),
])
def test_bad_specs_are_rejected(make, message):
    with pytest.raises(SolverInputError, match=message):
        make()


def test_rotations_must_match_the_poses(body):
    model, heads, tails, axes = body
    with pytest.raises(SolverInputError, match="rotations must have shape"):
        rig_limits({}, model, heads, tails, axes[:, :-1], {})
