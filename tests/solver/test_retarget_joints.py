"""Retargeting measures joints and soles, never the tails an importer left, and takes the heading from the
skeletons (solver/retarget/rig.py, soles.py, plan.py).

Rigs are the CMU skeletons of tests/solver/test_retarget.py: the same rig with its tails a hundred times as
long (as Blender's glTF importer leaves them), turned in its data to face ±X/±Y, and with a skinned sole below
its joints; every expectation is computed here from the tidy rig's own plan or geometry."""

import numpy as np
import pytest

from fullbody_adjust.solver.retarget import motion as rt

from .test_retarget import FPS, WALK, _rotation_about, cmu_rig, source_pose

FRAMES = np.arange(1, 241)
SETTINGS = rt.RetargetSettings(fps=FPS)


def far_tails(rig, factor=100.0, leaves=False):
    """The rig with the tail of every bone that has a next joint (a child starting apart from its head)
    ``factor`` times as far along its Y axis, and with ``leaves`` every other bone's too: what Blender's glTF
    importer leaves."""
    heads = rig.rest[:, :3, 3]
    jointed = np.zeros(len(rig), dtype=bool)
    for child, parent in enumerate(rig.parents):
        if parent >= 0 and np.linalg.norm(heads[child] - heads[parent]) > 1e-6:
            jointed[parent] = True
    lengths = np.where(jointed | leaves, rig.lengths * factor, rig.lengths)
    return rt.Rig(rig.names, rig.parents, rig.rest, lengths, rig.connected, rig.groups, rig.matrix_world)


def turned_data(rig, angle):
    """The rig with its rest data turned by ``angle`` about Z (the turn applied to the data, object untouched):
    the same character facing another way."""
    turn = np.eye(4)
    turn[:3, :3] = _rotation_about(np.array([0.0, 0.0, 1.0]), angle)
    return rt.Rig(rig.names, rig.parents, turn @ rig.rest, rig.lengths, rig.connected, rig.groups,
                  rig.matrix_world), turn


def plan(source, pose, target):
    return rt.plan_retarget(source, pose, target, np.tile(np.eye(4), (len(target), 1, 1)), SETTINGS)


def test_tails_far_past_the_next_joint_change_nothing():
    """Every bone's tail 100 times as far (leaves kept): the same joint lengths, legs, soles and the same
    plan, start pose and targets, as the tidy rig's."""
    source = cmu_rig(WALK)
    pose = source_pose(WALK, source, FRAMES)
    tidy = cmu_rig(WALK, scale=0.9, group_scales={"leg.L": 1.1, "leg.R": 1.1})
    far = far_tails(tidy)
    assert np.abs(far.lengths - tidy.lengths).max() > 1.0  # the importer's tails really are far
    np.testing.assert_allclose(far.lengths_joint, tidy.lengths_joint, atol=1e-12)
    assert rt.leg_length(far) == pytest.approx(rt.leg_length(tidy), abs=1e-12)
    a, b = plan(source, pose, tidy), plan(far_tails(source), pose, far)
    size = rt.leg_length(tidy)
    np.testing.assert_allclose(b.world_targets, a.world_targets, atol=1e-9 * size)
    np.testing.assert_allclose(b.start_pose, a.start_pose, atol=1e-9 * size)
    np.testing.assert_allclose(b.tails, a.tails, atol=1e-9 * size)
    assert b.ground == pytest.approx(a.ground, abs=1e-12)


def test_far_leaf_tails_are_not_soles():
    """The toes' leaf tails 100 times as long (pointing through the floor as the importer may leave them):
    they are no part of the sole (its heads only), the floor is where the source's soles are, and the
    planted soles of the target rest on it, never below."""
    raised = np.eye(4)
    raised[2, 3] = 1.0  # a metre up: its lowest joints are the floor (not the ground plane under unseen feet)
    source = far_tails(cmu_rig(WALK, world=raised), leaves=True)
    pose = source_pose(WALK, source, FRAMES)
    target = far_tails(cmu_rig(WALK, scale=1.1), leaves=True)
    for rig in (source, target):
        for foot in rt.FEET:
            bones = rig.descendants(rig.groups[foot][0])
            np.testing.assert_allclose(rig.soles[foot][0], rig.rest[bones, :3, 3], atol=1e-12)
    p = plan(source, pose, target)
    s_lowest = np.minimum(*(pose[:, source.descendants(source.groups[f][0]), 2, 3].min(axis=1) for f in rt.FEET)) + 1.0
    assert p.ground == pytest.approx(np.percentile(s_lowest, 2), abs=1e-12)
    for k, foot in enumerate(rt.FEET):
        sole = rt.effector_points(target, p.start_pose, foot)
        sole = sole - sole[:, :1] + p.world_targets[:, 2 + k, None]  # the foot where its ankle is planned
        lowest = sole[..., 2].min(axis=1)
        assert lowest.min() >= p.ground - 1e-9
        held = p.contacts[:, 2 + k]
        assert held.sum() > 0.3 * len(FRAMES)
        np.testing.assert_allclose(lowest[held], p.ground, atol=1e-9)


def _travel(rig, p):
    hips = rt.hip_centres(rig, rig.world_points(p.start_pose)[0])
    return hips[-1, :2] - hips[0, :2]


def _turn_z(angle):
    return _rotation_about(np.array([0.0, 0.0, 1.0]), angle)


def _toes_forward(rig):
    """Unit horizontal mean of the two ankles' offsets to their toe joints (the CMU feet splay 4.7 and 5.9
    degrees outward, so this is 0.7 degrees off -Y)."""
    heads = rig.world_points(rig.rest)[0]
    toes = np.mean([heads[rig.names.index(f"{s}ToeBase")] - heads[rig.groups[f"foot.{s[0]}"][0]]
                    for s in ("Left", "Right")], axis=0) * [1.0, 1.0, 0.0]
    return toes / np.linalg.norm(toes)


def _yaw(v):
    return np.arctan2(v[1], v[0])


@pytest.mark.parametrize("source_turn", [0.0, 0.5 * np.pi])
@pytest.mark.parametrize("target_turn", [0.0, 0.5 * np.pi, np.pi, -0.5 * np.pi])
def test_the_target_faces_its_travel_as_the_source_faces_its_own(source_turn, target_turn):
    """Source and target characters facing -Y, +X, +Y or -X in their data (objects untouched): the target's
    rest forward (from hips and feet) turned by the source's heading change is where it walks, as the source
    walks along its own; every limb segment points, in the target's body frame, where the source's points in
    its own; the target faces -Y (its rest) turned by the target's turn."""
    plain = cmu_rig(WALK)
    source, s_turn = turned_data(plain, source_turn)
    pose = s_turn @ source_pose(WALK, plain, FRAMES)  # the same motion in the turned data
    target, _ = turned_data(cmu_rig(WALK, scale=1.2), target_turn)
    forward = rt.rest_forward(target)
    np.testing.assert_allclose(forward, _turn_z(target_turn) @ _toes_forward(plain), atol=1e-9)
    assert _toes_forward(plain) @ [0.0, -1.0, 0.0] > np.cos(np.radians(1.0))  # the CMU rig faces -Y
    p = plan(source, pose, target)
    s_hips = rt.hip_centres(source, source.world_points(pose)[0])
    s_travel = s_hips[-1, :2] - s_hips[0, :2]
    t_travel = _travel(target, p)
    assert np.linalg.norm(t_travel) > 1.0
    relative_s = _yaw(s_travel) - _yaw(rt.rest_forward(source)[:2])
    relative_t = _yaw(t_travel) - _yaw(forward[:2])
    assert abs((relative_t - relative_s + np.pi) % (2 * np.pi) - np.pi) < np.radians(1.0)
    # Limb directions in each body's own rest frame agree (the source's angles carried over).
    s_heads, s_ends = source.world_points(pose)
    t_heads, t_ends = target.world_points(p.start_pose)
    s_frame = rt.body_frame(source, *rt.rest_points(source))
    t_frame = rt.body_frame(target, *rt.rest_points(target))
    for group in ("arm.L", "arm.R", "leg.L", "leg.R"):
        s_joints = rt.chain_joints(source, group, s_heads, s_ends)[:, -3:]
        t_joints = rt.chain_joints(target, group, t_heads, t_ends)[:, -3:]
        s_dir = np.diff(s_joints, axis=1) @ s_frame
        t_dir = np.diff(t_joints, axis=1) @ t_frame
        cos = np.sum(s_dir * t_dir, axis=-1) / np.linalg.norm(s_dir, axis=-1) / np.linalg.norm(t_dir, axis=-1)
        assert np.degrees(np.arccos(np.clip(cos, -1, 1))).max() < 1e-3  # arccos near 1: 1e-8 rad rounding


def test_the_feet_say_where_a_character_faces_when_its_hips_are_yawed():
    """GDQuest's mannequin has its hip line 13 degrees off its face and toes: the rest forward follows the toes
    (a hip line turned, the legs and feet as they were), and the hips still decide where the feet say nothing."""
    rig = cmu_rig(WALK)
    plain = rt.rest_forward(rig)
    rest = rig.rest.copy()
    hips = [rig.groups["leg.L"][0], rig.groups["leg.R"][0]]
    centre = rest[hips, :3, 3].mean(axis=0)
    turn = _rotation_about(np.array([0.0, 0.0, 1.0]), np.radians(13.0))
    rest[hips, :3, 3] = (rest[hips, :3, 3] - centre) @ turn.T + centre
    yawed = rt.Rig(rig.names, rig.parents, rest, rig.lengths, rig.connected, rig.groups, rig.matrix_world)
    hip_forward = np.cross(*rt.body_frame(yawed, *rt.rest_points(yawed))[:, [0, 2]].T)
    assert np.degrees(np.arccos(np.dot(hip_forward[:2], plain[:2]) / np.linalg.norm(hip_forward[:2]))) > 12.0
    np.testing.assert_allclose(rt.rest_forward(yawed), plain, atol=1e-9)


def test_an_object_turn_undone_in_the_data_changes_nothing():
    """A character whose data faces +X and whose object turns it back to -Y moves in the world exactly as the
    plain one: the heading comes from the skeleton in the world, not from the object's axes."""
    source = cmu_rig(WALK)
    pose = source_pose(WALK, source, FRAMES)
    plain = cmu_rig(WALK, scale=1.2)
    turned, turn = turned_data(plain, 0.5 * np.pi)
    back = rt.Rig(turned.names, turned.parents, turned.rest, turned.lengths, turned.connected, turned.groups,
                  np.linalg.inv(turn))
    a, b = plan(source, pose, plain), plan(source, pose, back)
    np.testing.assert_allclose(b.world_targets, a.world_targets, atol=1e-9)
    np.testing.assert_allclose(back.world_points(b.start_pose)[0], plain.world_points(a.start_pose)[0], atol=1e-9)


def _with_box_soles(rig, depth, half_length, half_width):
    """The rig with a skinned sole under each foot: the four bottom corners of a box ``depth`` below the
    foot's lowest joint, around the ankle-to-toe line, the heel corners on the foot bone, the toe corners
    shared half and half between the foot and toe bones (as skinning weights are)."""
    soles = {}
    for foot in rt.FEET:
        ankle = rig.groups[foot][0]
        toe = [b for b in rig.descendants(ankle) if rig.parents[b] == ankle][0]
        heads = rig.rest[:, :3, 3]
        low = heads[rig.descendants(ankle), 2].min() - depth
        along = heads[toe] - heads[ankle]
        along[2] = 0.0
        along /= np.linalg.norm(along)
        side = np.cross([0.0, 0.0, 1.0], along)
        middle = heads[ankle] + 0.5 * (heads[toe] - heads[ankle])
        corners = [middle + a * half_length * along + s * half_width * side for a in (-1, 1) for s in (-1, 1)]
        points = np.array([[c[0], c[1], low] for c in corners])
        bones = np.array([[ankle, -1], [ankle, -1], [ankle, toe], [ankle, toe]])
        weights = np.array([[1.0, 0.0], [1.0, 0.0], [0.5, 0.5], [0.5, 0.5]])
        soles[foot] = (points, bones, weights)
    return rt.Rig(rig.names, rig.parents, rig.rest, rig.lengths, rig.connected, rig.groups, rig.matrix_world,
                  soles=soles)


def test_a_skinned_sole_below_the_joints_stands_on_the_floor():
    """A target whose mesh soles lie 4 cm below its foot joints: on planted frames its skinned soles (linear
    blend skinning computed here) rest on the floor, never below it; the ankle stands higher than on the same
    rig without a mesh, by about as much as its soles lie lower at rest (more where the box's heel, which the
    bare CMU foot lacks, is what touches)."""
    source = cmu_rig(WALK)
    pose = source_pose(WALK, source, FRAMES)
    bare = cmu_rig(WALK, scale=1.1)
    shod = _with_box_soles(bare, 0.04, 0.12, 0.04)
    a, b = plan(source, pose, bare), plan(source, pose, shod)
    for k, foot in enumerate(rt.FEET):
        points, bones, weights = shod.soles[foot]
        skin = np.zeros((len(FRAMES), len(points), 3))
        for i in range(bones.shape[1]):
            valid = bones[:, i] >= 0
            m = b.start_pose[:, bones[valid, i]] @ np.linalg.inv(shod.rest[bones[valid, i]])
            moved = np.einsum("fpij,pj->fpi", m[..., :3, :3], points[valid]) + m[..., :3, 3]
            skin[:, valid] += weights[valid, i, None] * moved
        skin = shod.to_world(skin)
        ankle = shod.world_points(b.start_pose)[0][:, shod.groups[foot][0]]
        skin = skin - ankle[:, None] + b.world_targets[:, 2 + k, None]
        lowest = skin[..., 2].min(axis=1)
        held = b.contacts[:, 2 + k]
        assert held.sum() > 0.3 * len(FRAMES)
        assert lowest.min() >= b.ground - 1e-9
        np.testing.assert_allclose(lowest[held], b.ground, atol=1e-9)
        lift = b.world_targets[held, 2 + k, 2] - a.world_targets[held, 2 + k, 2]
        thicker = bare.soles[foot][0][:, 2].min() - points[:, 2].min()  # at rest: 4 cm below the joints
        assert thicker > 0.03 and np.median(lift) > 0.75 * thicker


def test_joints_a_little_above_the_ground_plane_stand_on_it():
    """A source without a mesh whose lowest joints rest 5 cm above z = 0 (a game character's toes inside a
    foot we do not see) stands on z = 0; raised a metre, or with a skinned sole, its own lowest points are the
    floor."""
    plain = cmu_rig(WALK)
    pose = source_pose(WALK, plain, FRAMES)
    lowest = np.percentile(np.minimum(*(plain.sole_points(pose, f)[..., 2].min(axis=1) for f in rt.FEET)), 2)

    def lifted(height):
        world = np.eye(4)
        world[2, 3] = height - lowest  # its lowest joints (2nd percentile) at ``height``
        return cmu_rig(WALK, world=world)

    assert rt.source_floor(lifted(0.05), pose) == 0.0
    assert rt.source_floor(lifted(1.0), pose) == pytest.approx(1.0, abs=1e-9)
    shod = _with_box_soles(lifted(0.05), 0.0, 0.1, 0.04)  # a mesh sole as low as the lowest joint at rest
    assert rt.source_floor(shod, pose) > 0.03
