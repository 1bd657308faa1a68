"""How high the body and its free feet stand. rise.fold_room: a held foot nearer its hip than the leg can fold (a long
shin on a short thigh, the knee at its limit) raises the whole body, smoothly, until every held or blending foot
lies at least the folded distance from its hip; a foot blending into its hold rises partly with the body, and the
rise takes that into account. plan._stand_in_place: feet the source never holds on the floor move up or down
together, each apart from the other by no more than a rig's asymmetry, so the legs keep the source's angles to each
other."""

import numpy as np

from fullbody_adjust.solver.retarget import feet, motion as rt, plan, rise

FRAMES, STEP, INNER = 40, 0.02, 0.3


def _case():
    bases = np.zeros((FRAMES, 4, 3))
    bases[..., 2] = 1.0  # shoulders and hips 1 m up
    free = bases + [0.0, 0.0, -0.5]  # every hand and foot 0.5 below its base
    squat = 0.5 - 0.4 * np.sin(np.linspace(0.0, np.pi, FRAMES))  # the held foot up to 0.1 below its hip
    held_point = np.stack([np.full(FRAMES, 0.05), np.zeros(FRAMES), 1.0 - squat], axis=1)
    weight = np.clip(np.concatenate([np.linspace(0.0, 1.0, 8), np.ones(FRAMES - 16), np.linspace(1.0, 0.0, 8)]),
                     0.0, 1.0)  # blended in and out over 7 frames

    def held(paths):
        out = paths.copy()
        out[:, 3] = weight[:, None] * held_point + (1.0 - weight[:, None]) * paths[:, 3]  # foot.R held
        return out

    fixed = np.zeros((FRAMES, 4), dtype=bool)
    fixed[:, 3] = weight > 0.0
    return held, free, bases, fixed


def _nearest(held, free, bases, shift):
    return np.linalg.norm(held(free + shift[:, None]) - bases - shift[:, None], axis=-1)[:, 3]


def test_the_body_rises_until_the_held_foot_is_as_far_from_its_hip_as_the_leg_folds():
    held, free, bases, fixed = _case()
    shift = np.zeros((FRAMES, 3))
    shift[:, 0] = np.linspace(0.0, 0.1, FRAMES)  # a shift already found, which the rise keeps
    inner = np.full(4, INNER)
    before = _nearest(held, free, bases, shift)
    assert before[fixed[:, 3]].min() < 0.2  # the foot 0.1 below its hip at the deepest: nearer than the leg folds
    out = rise.fold_room(held, free, bases, shift, fixed, inner, STEP)
    after = _nearest(held, free, bases, out)
    assert after[fixed[:, 3]].min() >= INNER * (1.0 - 1e-6)
    np.testing.assert_array_equal(out[:, :2], shift[:, :2])  # only up
    lift = out[:, 2] - shift[:, 2]
    assert lift.min() >= 0.0 and np.abs(np.diff(lift)).max() <= STEP * (1.0 + 1e-9)  # smoothly
    assert lift[0] == 0.0 and lift[-1] == 0.0  # nothing held there
    assert lift.max() > np.sqrt(INNER ** 2 - 0.05 ** 2) - 0.1 - 1e-9  # at least what the deepest frame needs


def test_nothing_moves_where_every_held_foot_is_far_enough():
    held, free, bases, fixed = _case()
    shift = np.zeros((FRAMES, 3))
    out = rise.fold_room(held, free, bases, shift, fixed, np.full(4, 0.05), STEP)
    np.testing.assert_array_equal(out, shift)


def _in_place(frames=20):
    """A source whose soles rest on the floor (z = 0) on half the frames, the left at 0, the right 2 cm up; a target
    whose free ankles are 5 cm up, 8 cm (left) and 12 cm (right, pitched) above their soles."""
    s_points = {e: np.zeros((frames, 3, 3)) for e in rt.EFFECTORS}
    rise_and_fall = 0.1 * np.abs(np.sin(np.linspace(0.0, 2.0 * np.pi, frames)))
    for e, up in zip(rt.FEET, (0.0, 0.02)):
        s_points[e][:, :, 2] = (up + rise_and_fall)[:, None] + [0.07, 0.0, 0.01]  # ankle, then its sole
    free = np.zeros((frames, len(rt.EFFECTORS), 3))
    free[..., 2] = 0.05
    soles = np.tile([0.08, 0.12], (frames, 1))
    return free, s_points, soles


def test_feet_standing_in_place_move_together_apart_from_a_rigs_asymmetry():
    feet = [rt.EFFECTORS.index(e) for e in rt.FEET]
    for spread, expected in ((0.01, (0.04, 0.06)), (0.1, (0.03, 0.07)), (0.0, (0.05, 0.05))):
        free, s_points, soles = _in_place()
        plan._stand_in_place(free, {e: [] for e in rt.EFFECTORS}, s_points, soles, 0.0, 0.9, rt.RetargetSettings(),
                             spread)
        # on its own each sole on the floor: the left moves 0.03 and the right 0.07, their mean 0.05
        np.testing.assert_allclose(free[:, feet, 2], np.broadcast_to(0.05 + np.array(expected), (len(free), 2)),
                                   atol=1e-12)
        np.testing.assert_array_equal(free[:, [0, 1], 2], 0.05)  # the hands ride as they were


def test_a_foot_held_on_the_floor_stands_by_its_holds_and_the_other_by_its_own_sole():
    free, s_points, soles = _in_place()
    found = {e: [] for e in rt.EFFECTORS}
    found["foot.R"] = [rt.Contact("foot.R", 0, 10, rt.GROUND, 0.0)]  # half the frames: its stances are held
    plan._stand_in_place(free, found, s_points, soles, 0.0, 0.9, rt.RetargetSettings(), 0.0)
    np.testing.assert_allclose(free[:, rt.EFFECTORS.index("foot.L"), 2], 0.05 + 0.03, atol=1e-12)
    np.testing.assert_array_equal(free[:, rt.EFFECTORS.index("foot.R"), 2], 0.05)


def test_a_foot_lowered_to_stand_in_place_never_stretches_a_leg_further_than_its_own_or_the_reach_margin_in_the_air():
    hip = np.array([0.0, 0.0, 1.0])
    heights = np.array([0.05, 0.115, 0.2, 0.3])  # the leg nearly straight down to well bent
    ankles = np.stack([np.full(4, 0.1), np.zeros(4), heights], axis=1)
    hips = np.broadcast_to(hip, (4, 3))
    longest = 0.9
    moved = feet.lowered_within_reach(ankles, hips, -0.02, longest)
    own = np.linalg.norm(ankles - hip, axis=1)
    after = np.linalg.norm(ankles + np.outer(moved, [0.0, 0.0, 1.0]) - hip, axis=1)
    assert own[0] > longest and own[-1] < longest - 0.02
    np.testing.assert_allclose(moved[0], 0.0, atol=1e-12)  # already beyond the margin: it stays
    np.testing.assert_allclose(after[1], longest, atol=1e-12)  # lowered as far as the margin lets it
    assert -0.02 < moved[1] < 0.0
    np.testing.assert_allclose(moved[3], -0.02, atol=1e-12)  # room to spare: the whole way
    assert (after <= np.maximum(own, longest) + 1e-12).all()
    np.testing.assert_array_equal(feet.lowered_within_reach(ankles, hips, 0.02, longest), 0.02)  # raised freely
    # Through _stand_in_place: with the hips given, a foot standing in place is lowered only where its leg has room.
    free, s_points, soles = _in_place()
    left, right = (rt.EFFECTORS.index(e) for e in rt.FEET)
    free[:, [left, right], 2] = 0.3  # both feet 0.2 m too high for their soles: lowered 0.2 (spread 0)
    hips = np.broadcast_to([[0.0, 0.0, 0.6], [0.0, 0.0, 0.3 + longest]], (len(free), 2, 3))
    plan._stand_in_place(free, {e: [] for e in rt.EFFECTORS}, s_points, soles, 0.0, 0.9, rt.RetargetSettings(),
                         0.0, hips, [longest, longest])
    np.testing.assert_allclose(free[:, left, 2], 0.1, atol=1e-12)  # room to spare
    resting = plan.resting_frames(s_points)[:, 1]
    assert resting.any() and not resting.all()
    # where the source's sole is lowest, on the floor; elsewhere its leg is already at the margin: not lowered
    np.testing.assert_allclose(free[:, right, 2], np.where(resting, 0.1, 0.3), atol=1e-12)
