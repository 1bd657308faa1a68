"""A target whose feet are longer than the source's (for its legs), as game characters' often are (KayKit's
ankle stands 40% of a leg above its sole): it stands and walks with its legs as the source's, and its knees do
not snap at toe-off (solver/retarget/plan.py's body height, solver/retarget/feet.py)."""

import numpy as np

from fullbody_adjust.solver.retarget import motion as rt
from fullbody_adjust.solver.fullbody.adjust import adjust_frames
from fullbody_adjust.solver.retarget.feet import limit_toe_roll
from tests.solver.test_retarget import FPS, WALK, cmu_rig, source_pose, world_rotations

FRAMES = np.arange(1, 241)  # two seconds of the walk at 120 fps: both feet planted and lifted twice


def long_footed(rig, factor, drop=0.0):
    """The rig with every bone below each ankle (the toes) ``factor`` times as far from it, and as long, and
    ``drop`` leg lengths lower (an ankle standing higher above its sole)."""
    rest, lengths = rig.rest.copy(), np.array(rig.lengths, dtype=np.float64)
    for foot in ("foot.L", "foot.R"):
        ankle = rig.groups[foot][0]
        below = rig.descendants(ankle)[1:]
        rest[below, :3, 3] = rest[ankle, :3, 3] + factor * (rest[below, :3, 3] - rest[ankle, :3, 3])
        rest[below, 2, 3] -= drop * rt.leg_length(rig)
        lengths[below] *= factor
    return rt.Rig(names=rig.names, parents=rig.parents, rest=rest, lengths=lengths, connected=rig.connected,
                  groups=rig.groups, matrix_world=rig.matrix_world)


def extension(rig, pose, ankles, side):
    """(F,) hip joint to ankle (world points (F,3)) over the leg's length."""
    hip = rig.world_points(pose)[0][:, rig.groups[f"leg.{side}"][0]]
    return np.linalg.norm(ankles - hip, axis=-1) / rt.leg_length(rig)


def turns(rig, pose, bones):
    """(F-1,k) degrees each bone's world orientation turns from one frame to the next."""
    r = world_rotations(rig, pose)[:, bones]
    rel = np.swapaxes(r[:-1], -1, -2) @ r[1:]
    return np.degrees(np.arccos(np.clip((np.trace(rel, axis1=-2, axis2=-1) - 1.0) / 2.0, -1.0, 1.0)))


def test_an_in_place_walk_keeps_the_legs_of_the_source_on_a_long_footed_target():
    """The walk in place (the hips' travel taken out: the feet slide under the body, never held still) onto a
    target whose toes are twice as far from the ankle and a tenth of a leg lower: on every frame each ankle
    target lies as far from its hip joint, for the leg's length, as the source's ankle from its hip, within
    0.06 (the body stands as high as puts the target's soles on the floor where the source's are; scaled about
    the floor, the body stood as low as the source's and the feet raised out of the floor bent the knees, the
    ankles up to 0.2 of a leg nearer the hips)."""
    source = cmu_rig(WALK)
    pose = source_pose(WALK, source, FRAMES)
    hips = pose[:, source.groups["root"][0], :3, 3]
    pose[..., :2, 3] -= (hips[:, :2] - hips[:1, :2])[:, None]
    target = long_footed(cmu_rig(WALK, scale=0.9), 2.0, 0.1)
    plan = rt.plan_retarget(source, pose, target, np.tile(np.eye(4), (len(target), 1, 1)),
                            rt.RetargetSettings(fps=FPS))
    assert not plan.contacts.any()
    for k, side in ((2, "L"), (3, "R")):
        s_ankle = rt.effector_points(source, pose, f"foot.{side}")[:, 0]
        difference = (extension(target, plan.start_pose, plan.world_targets[:, k], side)
                      - extension(source, pose, s_ankle, side))
        assert np.abs(difference).max() <= 0.06, (side, np.abs(difference).max())


def test_a_long_footed_target_turns_its_legs_as_the_source_turns_its_own():
    """The walk at 24 frames per second, solved onto a target whose toes are twice as far from the ankle and a
    tenth of a leg lower: its thighs and shins turn from frame to frame by at most 5 degrees more than the
    source's on the same frames, and never further than 1 degree past the source's largest turn (its toes dug
    into the floor at toe-off and lifting the ankle out bent the knee: 8 degrees more, 21.4 against 18.2)."""
    source = cmu_rig(WALK)
    pose = source_pose(WALK, source, np.arange(1, 317, 5))
    target = long_footed(cmu_rig(WALK, scale=0.9), 2.0, 0.1)
    plan = rt.plan_retarget(source, pose, target, np.tile(np.eye(4), (len(target), 1, 1)),
                            rt.RetargetSettings(fps=24.0))
    model, bones = rt.body_model(target)
    start, heads, tails = plan.start_pose[:, bones], plan.heads[:, bones], plan.tails[:, bones]
    result = adjust_frames(model, heads, tails, plan.targets, rt.EFFECTORS, [2, 2, 3, 3],
                           limits=rt.motion_limits(model, start, heads, tails))
    assert np.all(result.residuals <= 1e-4 * rt.leg_length(target))
    solved = rt.solved_pose(plan, result.rotations, result.heads, bones)
    legs = [b for side in "LR" for b in target.groups[f"leg.{side}"]]
    s_legs = [b for side in "LR" for b in source.groups[f"leg.{side}"]]
    t_turns, s_turns = turns(target, solved, legs), turns(source, pose, s_legs)
    assert (t_turns - s_turns).max() <= 5.0, (t_turns - s_turns).max()
    assert t_turns.max() <= s_turns.max() + 1.0, (t_turns.max(), s_turns.max())


def test_a_foot_is_turned_toes_up_about_its_ankle_as_far_as_asked_but_never_flatter_than_it_stands():
    """limit_toe_roll on the transferred walk, each foot asked to bring its sole within 0.8 of its height below
    the ankle: the ankles and legs stay where they were; each foot turns as one with its toes, only toes up;
    on every frame its sole comes within what was asked, or the foot has turned as far as its pitch on the
    frames it stands flat (the source's ankle at its lowest quarter) and no further."""
    target = long_footed(cmu_rig(WALK, scale=0.9), 2.0, 0.1)
    source = cmu_rig(WALK)
    pose = source_pose(WALK, source, FRAMES)
    ratio = rt.leg_length(target) / rt.leg_length(source)
    start = rt.transfer_pose(source, pose, target, np.tile(np.eye(4), (len(target), 1, 1)),
                             ratio * rt.hip_centres(source, source.world_points(pose)[0]))
    before = rt.ankle_above_sole(target, start)
    turned_pose = start.copy()
    angles = limit_toe_roll(source, pose, target, turned_pose, ratio, 0.8 * before)
    after = rt.ankle_above_sole(target, turned_pose)
    assert angles.max() > np.radians(10.0) and angles.min() >= 0.0
    heads = target.world_points(start)[0]
    hips = heads[:, target.groups["leg.L"][0]] - heads[:, target.groups["leg.R"][0]]
    forward = np.cross(hips, [0.0, 0.0, 1.0])
    forward[:, 2] = 0.0
    forward /= np.linalg.norm(forward, axis=1, keepdims=True)
    for i, foot in enumerate(("foot.L", "foot.R")):
        ankle = target.groups[foot][0]
        toes = target.descendants(ankle)[1]
        np.testing.assert_allclose(turned_pose[:, ankle, :3, 3], start[:, ankle, :3, 3], atol=1e-12)
        for b in target.descendants(ankle):  # the foot and toes turned together
            np.testing.assert_allclose(np.linalg.inv(turned_pose[:, ankle]) @ turned_pose[:, b],
                                       np.linalg.inv(start[:, ankle]) @ start[:, b], atol=1e-9)
        legs = target.groups[f"leg.{foot[-1]}"]
        np.testing.assert_array_equal(turned_pose[:, legs], start[:, legs])

        def pitch(p):
            ahead = p[:, toes, :3, 3] - p[:, ankle, :3, 3]  # identity object: armature space is the world
            return np.arctan2(-ahead[:, 2], np.sum(ahead * forward, axis=1))

        assert np.all(pitch(turned_pose) <= pitch(start) + 1e-9)  # toes up, if at all
        s_ankle = source.world_points(pose)[0][:, source.groups[foot][0], 2]
        stands = np.median(pitch(start)[s_ankle <= np.percentile(s_ankle, 25)])
        assert np.all((pitch(turned_pose) >= stands - 1e-9) | (angles[:, i] == 0.0))
        asked = after[:, i] <= 0.8 * before[:, i] + 1e-9
        assert np.all(asked | np.isclose(pitch(turned_pose), stands, atol=1e-6) | (pitch(start) <= stands))
        assert asked.any() and (~asked).any()
