"""Motion retargeting, numpy side (solver/retarget/motion.py): rotation channels, kinematics, the rotation transfer
between two bone mappings, contacts and effector targets, and the whole plan -> adjust_frames -> channels
path on CMU clips, with targets built from the same clips (scaled, A-posed, rolled, re-proportioned,
another trunk).

Every expectation is computed here from the rigs' own geometry; the CMU skeletons are built the way
Blender's BVH importer builds them (Z up), from tests/helpers/bvh.py."""

from functools import lru_cache

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from fullbody_adjust.solver.retarget import motion as rt
from fullbody_adjust.solver.fullbody.adjust import adjust_frames
from fullbody_adjust.solver.errors import SolverInputError
from tests.helpers.bvh import CMU_GROUPS, read_cmu

FPS = 120.0  # the CMU clips
Z_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])  # BVH Y up -> Blender Z up


# ---------------------------------------------------------------------------------------------------------
# Rigs built from CMU clips


def _bone_frame(direction, roll):
    """A rotation whose Y axis is ``direction``, turned by ``roll`` about it (as a bone's rest matrix)."""
    y = direction / np.linalg.norm(direction)
    helper = np.array([0.0, 0.0, 1.0]) if abs(y[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    x = np.cross(y, helper)
    x /= np.linalg.norm(x)
    z = np.cross(x, y)
    frame = np.stack([x, y, z], axis=1)
    c, s = np.cos(roll), np.sin(roll)
    return frame @ np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


@lru_cache(maxsize=None)
def _clip(name):
    return read_cmu(name)


def cmu_rig(clip_name, *, scale=1.0, group_scales=None, rolls=0.0, arm_drop=0.0, merge_spine=False,
            world=None):
    """(Rig, rest heads) of a CMU clip's skeleton, Z up. scale: every offset; group_scales: {group: factor}
    for the offsets of that group's bones; rolls: radians added to every bone's roll (bone i gets i*rolls);
    arm_drop: the upper arms' rest turned down by this angle about the body's forward axis (an A-pose);
    merge_spine: 'Spine' dropped (its child hangs from LowerBack), a 2-bone trunk; world: object matrix."""
    clip = _clip(clip_name)
    names, parents = list(clip.names), clip.parents.tolist()
    offsets = clip.offsets @ Z_UP.T * scale
    tails_local = clip.tail_offsets() @ Z_UP.T * scale
    index = {n: i for i, n in enumerate(names)}
    factor = np.ones(len(names))
    for group, f in (group_scales or {}).items():
        for bone in CMU_GROUPS[group]:
            factor[index[bone]] = f
    offsets = offsets * factor[:, None]
    if merge_spine:
        s = index["Spine"]
        for j, p in enumerate(parents):
            if p == s:
                parents[j] = parents[s]
                offsets[j] = offsets[j] + offsets[s]
        keep = [j for j in range(len(names)) if j != s]
        renumber = {old: new for new, old in enumerate(keep)}
        names = [names[j] for j in keep]
        parents = [renumber[parents[j]] if parents[j] >= 0 else -1 for j in keep]
        offsets, tails_local = offsets[keep], tails_local[keep]
        index = {n: i for i, n in enumerate(names)}
    heads = np.zeros((len(names), 3))
    for j, p in enumerate(parents):
        heads[j] = offsets[j] + (heads[p] if p >= 0 else 0.0)
    # Tails as the importer makes them: the children's mean head, else the clip's own tail offset.
    tails = heads + tails_local
    for j in range(len(names)):
        children = [c for c, p in enumerate(parents) if p == j]
        if children and np.linalg.norm(heads[children].mean(axis=0) - heads[j]) > 1e-6:
            tails[j] = heads[children].mean(axis=0)
    if arm_drop:
        for side, sign in (("L", 1.0), ("R", -1.0)):
            shoulder = index[CMU_GROUPS[f"arm.{side}"][1]]
            below = _descendants(parents, shoulder)
            turn = _rotation_about(np.array([0.0, -1.0, 0.0]), -sign * arm_drop)
            heads[below] = heads[shoulder] + (heads[below] - heads[shoulder]) @ turn.T
            tails[below] = heads[shoulder] + (tails[below] - heads[shoulder]) @ turn.T
    rest = np.tile(np.eye(4), (len(names), 1, 1))
    for j in range(len(names)):
        rest[j, :3, :3] = _bone_frame(tails[j] - heads[j], j * rolls)
        rest[j, :3, 3] = heads[j]
    groups = {g: tuple(index[b] for b in bones if b in index) for g, bones in CMU_GROUPS.items()}
    rig = rt.Rig(names=tuple(names), parents=parents, rest=rest, lengths=np.linalg.norm(tails - heads, axis=1),
                 connected=np.zeros(len(names), dtype=bool), groups=groups,
                 matrix_world=np.eye(4) if world is None else world)
    return rig


def _descendants(parents, bone):
    out = [bone]
    for j in range(bone + 1, len(parents)):
        if parents[j] in out:
            out.append(j)
    return out


def _rotation_about(axis, angle):
    axis = axis / np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


def source_pose(clip_name, rig, frames):
    """Armature-space pose matrices (F,J,4,4) of the clip on its own rig (a BVH joint's world rotation is
    identity at rest, so pose = [C R C^T @ rest rotation, C position])."""
    positions, rotations = _clip(clip_name).forward_kinematics(frames)
    pose = np.tile(np.eye(4), (len(frames), len(rig), 1, 1))
    pose[..., :3, :3] = Z_UP @ rotations @ Z_UP.T @ rig.rest[:, :3, :3]
    pose[..., :3, 3] = positions @ Z_UP.T
    return pose


def world_heads(rig, pose):
    return rig.world_points(pose)[0]


def mapped(rig):
    return sorted({b for bones in rig.groups.values() for b in bones})


def world_rotations(rig, pose):
    return rig.rotation @ pose[..., :3, :3] / np.linalg.norm(pose[..., :3, :3], axis=-2, keepdims=True)


def angle_between(a, b):
    cos = np.sum(a * b, axis=-1) / (np.linalg.norm(a, axis=-1) * np.linalg.norm(b, axis=-1))
    return np.arccos(np.clip(cos, -1.0, 1.0))


WALK = "cmu_07_01_walk.bvh"
PICKUP = "cmu_02_06_pickup_f0-1349.bvh"
CLIMB = "cmu_01_06_climb_sit_f360-1559.bvh"


# ---------------------------------------------------------------------------------------------------------
# Rotation channels


def _axis_matrix(axis, angle):
    c, s = np.cos(angle), np.sin(angle)
    return {0: np.array([[1, 0, 0], [0, c, -s], [0, s, c]]), 1: np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]),
            2: np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])}[axis]


angles3 = arrays(np.float64, 3, elements=st.floats(-3.1, 3.1))


@settings(deadline=None, max_examples=60)
@given(angles3, st.sampled_from(rt.EULER_ORDERS))
def test_euler_composes_in_the_order_of_its_mode(angles, order):
    """'XYZ' turns about X first: Rz @ Ry @ Rx, angles stored per axis (Blender's Euler)."""
    first, second, third = ("XYZ".index(a) for a in order)
    expected = (_axis_matrix(third, angles[third]) @ _axis_matrix(second, angles[second])
                @ _axis_matrix(first, angles[first]))
    np.testing.assert_allclose(rt.euler_to_matrices(angles, order), expected, atol=1e-12)


def smooth_rotations(seed, frames=200, speed=0.25):
    """A rotation sequence turning up to ``speed`` radians a frame about wandering axes (so Euler angles
    wrap and quaternions would flip hemisphere if taken independently)."""
    rng = np.random.default_rng(seed)
    out = np.empty((frames, 3, 3))
    current = _rotation_about(rng.normal(size=3), rng.uniform(0, np.pi))
    for f in range(frames):
        current = _rotation_about(rng.normal(size=3), rng.uniform(0, speed)) @ current
        out[f] = current
    return out


@pytest.mark.parametrize("mode", rt.EULER_ORDERS + ("QUATERNION", "AXIS_ANGLE"))
def test_rotation_channels_round_trip_continuously_from_the_reference(mode):
    matrices = smooth_rotations(7)
    size = {"QUATERNION": 4, "AXIS_ANGLE": 4}.get(mode, 3)
    reference = np.array([0.3, -0.2, 0.5, 0.1][:size]) + (2 * np.pi * np.array([2, -1, 0, 0][:size])
                                                          if size == 3 else 0.0)
    values = rt.rotation_channel(mode, matrices, reference)
    np.testing.assert_allclose(rt.rotation_matrices(mode, values), matrices, atol=1e-9)
    steps = np.abs(np.diff(values, axis=0))
    if mode == "QUATERNION":
        assert np.all(np.sum(values[1:] * values[:-1], axis=1) >= 0.0)  # never the long way round
        assert np.dot(values[0], reference) >= 0.0
    elif mode == "AXIS_ANGLE":
        assert np.all(steps[:, 0] < np.pi)
        assert np.all(np.sum(values[1:, 1:] * values[:-1, 1:], axis=1) > -0.5)  # the axis does not flip
    else:
        # Away from gimbal lock an Euler angle changes about as fast as the rotation; never by whole turns.
        assert np.all(steps < np.pi)
        assert np.all(np.abs(values[0] - reference) <= np.pi)


def test_rotation_channels_of_many_bones_at_once_equal_one_at_a_time():
    matrices = np.stack([smooth_rotations(s, frames=50) for s in range(3)], axis=1)  # (F,3 bones,3,3)
    for mode, size in (("QUATERNION", 4), ("ZXY", 3), ("AXIS_ANGLE", 4)):
        reference = np.linspace(-0.5, 0.5, 3 * size).reshape(3, size)
        together = rt.rotation_channel(mode, matrices, reference)
        for b in range(3):
            np.testing.assert_allclose(together[:, b], rt.rotation_channel(mode, matrices[:, b], reference[b]),
                                       atol=1e-12)


def test_unknown_rotation_mode_is_a_clear_error():
    with pytest.raises(SolverInputError, match="rotation mode"):
        rt.rotation_matrices("XXY", np.zeros(3))


# ---------------------------------------------------------------------------------------------------------
# Kinematics


def random_rig(seed, bones=12):
    rng = np.random.default_rng(seed)
    parents = [-1] + [int(rng.integers(0, j)) for j in range(1, bones)]
    rest = np.tile(np.eye(4), (bones, 1, 1))
    for j in range(bones):
        rest[j, :3, :3] = _rotation_about(rng.normal(size=3), rng.uniform(0, np.pi))
        rest[j, :3, 3] = rng.normal(size=3)
    connected = rng.random(bones) < 0.4
    connected[0] = False
    return rt.Rig(names=tuple(f"b{j}" for j in range(bones)), parents=parents, rest=rest,
                  lengths=rng.uniform(0.1, 1.0, bones), connected=connected,
                  groups={g: (0,) for g in ("root", "trunk", "arm.L", "arm.R", "hand.L", "hand.R", "leg.L",
                                            "leg.R", "foot.L", "foot.R")}), rng


def test_basis_from_pose_inverts_forward_kinematics():
    rig, rng = random_rig(3)
    frames = 5
    basis = np.tile(np.eye(4), (frames, len(rig), 1, 1))
    for f in range(frames):
        for j in range(len(rig)):
            basis[f, j, :3, :3] = _rotation_about(rng.normal(size=3), rng.uniform(0, 3)) * rng.uniform(0.5, 2, 3)
            basis[f, j, :3, 3] = rng.normal(size=3)
    pose = rt.forward_kinematics(rig, basis)
    expected = basis.copy()
    expected[:, rig.connected, :3, 3] = 0.0  # a connected bone ignores its location
    np.testing.assert_allclose(rt.basis_from_pose(rig, pose, np.arange(len(rig))), expected, atol=1e-9)
    # Composition as Blender: pose = parent pose @ parent_rest^-1 @ rest @ basis.
    j = int(np.nonzero(rig.parents >= 0)[0][-1])
    p = rig.parents[j]
    np.testing.assert_allclose(pose[:, j], pose[:, p] @ np.linalg.inv(rig.rest[p]) @ rig.rest[j] @ expected[:, j],
                               atol=1e-9)


def test_non_uniform_object_scale_is_refused():
    rig, _ = random_rig(1)
    with pytest.raises(SolverInputError, match="uniform"):
        rt.Rig(rig.names, rig.parents, rig.rest, rig.lengths, rig.connected, rig.groups, np.diag([1, 2, 1, 1.0]))


# ---------------------------------------------------------------------------------------------------------
# Rotation transfer


FRAMES = np.arange(1, 151)  # frame 0 is the T-pose


def scaled_about(points, anchor_from, anchor_to, ratio):
    return anchor_to + ratio * (points - anchor_from)


def anchors(source, target, ground):
    a_s = rt.hip_centres(source, rt.rest_points(source)[0])
    a_t = rt.hip_centres(target, rt.rest_points(target)[0])
    a_s[2] = a_t[2] = ground
    return a_s, a_t


def test_a_scaled_copy_moves_exactly_as_the_source_scaled():
    """Same skeleton, 1.2 times the size, other bone rolls, its object moved, turned and scaled: every
    target joint follows the source's world trajectory, scaled by 1.2 about the ground below the hips (the
    motion is world space: the target faces where the source faces, whatever its object's turn)."""
    source = cmu_rig(WALK)
    world = np.eye(4)
    world[:3, :3] = _rotation_about(np.array([0.0, 0.0, 1.0]), 0.7) * 0.5
    world[:3, 3] = (2.0, -1.0, 0.0)
    target = cmu_rig(WALK, scale=2.4, rolls=0.37, world=world)  # 2.4 armature units x 0.5 object scale
    pose = source_pose(WALK, source, FRAMES)
    s_heads = world_heads(source, pose)
    ground = 0.0
    a_s, a_t = anchors(source, target, ground)
    ratio = rt.leg_length(target) / rt.leg_length(source)
    assert ratio == pytest.approx(1.2)
    hips = scaled_about(rt.hip_centres(source, s_heads), a_s, a_t, ratio)
    moved = rt.transfer_pose(source, pose, target, np.tile(np.eye(4), (len(target), 1, 1)), hips)
    s_tails = source.world_points(pose)[1]
    t_heads, t_tails = target.world_points(moved)
    body = mapped(target)
    # Unmapped bones (toes, fingers) keep their rest pose: only their heads ride along with a mapped parent.
    riding = [j for j in range(len(target)) if j in body or target.parents[j] in body]
    np.testing.assert_allclose(t_heads[:, riding], a_t + ratio * (s_heads[:, riding] - a_s), atol=1e-9)
    np.testing.assert_allclose(t_tails[:, body], a_t + ratio * (s_tails[:, body] - a_s), atol=1e-9)


def test_an_a_pose_target_points_its_limbs_where_the_source_points():
    """Target arms at rest 40 degrees lower (A-pose) and other rolls: each limb segment still points along
    its source segment on every frame; the spine and pelvis turn as the source's do."""
    source = cmu_rig(WALK)
    target = cmu_rig(WALK, scale=0.9, rolls=0.2, arm_drop=np.radians(40))
    pose = source_pose(WALK, source, FRAMES)
    moved = rt.transfer_pose(source, pose, target, np.tile(np.eye(4), (len(target), 1, 1)),
                             np.zeros((len(FRAMES), 3)))
    s_heads, s_tails = source.world_points(pose)
    t_heads, t_tails = target.world_points(moved)
    for group in ("arm.L", "arm.R", "leg.L", "leg.R"):
        s_joints = rt.chain_joints(source, group, s_heads, s_tails)
        t_joints = rt.chain_joints(target, group, t_heads, t_tails)
        limb = slice(-2, None)  # upper arm and forearm; thigh and shin
        angles = angle_between(np.diff(s_joints, axis=1)[:, limb], np.diff(t_joints, axis=1)[:, limb])
        assert angles.max() < 1e-7, group
    # Rest-relative world rotation change of the trunk: the same as the source's.
    s_rot, t_rot = world_rotations(source, pose), world_rotations(target, moved)
    s_rest, t_rest = world_rotations(source, source.rest), world_rotations(target, target.rest)
    for s, t in zip(source.groups["trunk"], target.groups["trunk"]):
        np.testing.assert_allclose(s_rot[:, s] @ s_rest[s].T, t_rot[:, t] @ t_rest[t].T, atol=1e-9)


def test_hips_swung_by_moving_the_thighs_turn_the_target_pelvis():
    """Some game rigs swing the hips by moving the thighs' heads, the pelvis bone turning less or not at all
    (KayKit's run: location keys on upperleg.l/r). The source here is the walk with its pelvis held at rest and
    its hip joints where the walk puts them: the target's hips' line turns as the source's does on every frame
    (before: it kept its rest direction), and a rigid pelvis still turns exactly as its bone does."""
    source = cmu_rig(WALK)
    target = cmu_rig(WALK, scale=1.1, rolls=0.3)
    pose = source_pose(WALK, source, FRAMES)
    pelvis = source.groups["root"][0]
    left, right = source.groups["leg.L"][0], source.groups["leg.R"][0]

    def hip_lines(rig, p):
        heads = world_heads(rig, p)
        line = heads[:, rig.groups["leg.L"][0]] - heads[:, rig.groups["leg.R"][0]]
        return line / np.linalg.norm(line, axis=-1, keepdims=True)

    swung = pose.copy()
    swung[:, pelvis, :3, :3] = source.rest[pelvis, :3, :3]  # the pelvis bone does not turn...
    lines = hip_lines(source, swung)  # ...its hip joints do (they keep the walk's positions)
    turned = np.degrees(angle_between(lines, lines[:1])).max()
    assert turned > 5.0  # the walk's hips do swing
    basis = np.tile(np.eye(4), (len(target), 1, 1))
    moved = rt.transfer_pose(source, swung, target, basis, np.zeros((len(FRAMES), 3)))
    np.testing.assert_allclose(hip_lines(target, moved), lines, atol=1e-9)
    rigid = rt.transfer_pose(source, pose, target, basis, np.zeros((len(FRAMES), 3)))
    t = target.groups["root"][0]
    s_turn = world_rotations(source, pose)[:, pelvis] @ world_rotations(source, source.rest[None])[0, pelvis].T
    t_turn = world_rotations(target, rigid)[:, t] @ world_rotations(target, target.rest[None])[0, t].T
    np.testing.assert_allclose(t_turn, s_turn, atol=1e-9)


def test_a_two_bone_trunk_follows_a_three_bone_one():
    """Counts differ: target trunk bones take the blended changes of the source bones at the same
    proportional place, so the chest (SC) direction from the pelvis follows the source's."""
    source = cmu_rig(PICKUP)
    target = cmu_rig(PICKUP, merge_spine=True)
    assert len(target.groups["trunk"]) == 2 and len(source.groups["trunk"]) == 3
    pairs = {p.target: p for p in rt.pair_bones(source, target)}
    for t in target.groups["trunk"]:
        assert sum(pairs[t].weights) == pytest.approx(1.0)
        assert len(pairs[t].sources) == 2  # between two source bones
    frames = np.arange(1, 1350, 10)
    pose = source_pose(PICKUP, source, frames)
    moved = rt.transfer_pose(source, pose, target, np.tile(np.eye(4), (len(target), 1, 1)),
                             np.zeros((len(frames), 3)))
    s_heads, s_tails = source.world_points(pose)
    t_heads, t_tails = target.world_points(moved)
    s_trunk = rt.chain_joints(source, "trunk", s_heads, s_tails)
    t_trunk = rt.chain_joints(target, "trunk", t_heads, t_tails)
    bend = angle_between(s_trunk[:, -1] - s_trunk[:, 0], s_trunk[:, 1] - s_trunk[:, 0])
    error = angle_between(s_trunk[:, -1] - s_trunk[:, 0], t_trunk[:, -1] - t_trunk[:, 0])
    # The merged spine cannot copy the source's curve exactly: the chest direction stays within the
    # source's own bend of the spine (or a degree).
    assert np.all(error <= np.maximum(bend, np.radians(1.0)))
    assert np.degrees(error.max()) < 10.0


def test_unmapped_target_bones_keep_their_own_local_pose():
    """A bone outside the bone map that is no finger both rigs name (the CMU finger base, the hip joint)."""
    source = cmu_rig(WALK)
    target = cmu_rig(WALK, scale=1.1)
    basis = np.tile(np.eye(4), (len(target), 1, 1))
    finger = target.names.index("LeftFingerBase")
    hip_joint = target.names.index("LHipJoint")
    for j, angle in ((finger, 0.4), (hip_joint, -0.3)):
        basis[j, :3, :3] = _rotation_about(np.array([1.0, 0.2, 0.0]), angle)
    pose = source_pose(WALK, source, FRAMES[:20])
    moved = rt.transfer_pose(source, pose, target, basis, np.zeros((20, 3)))
    local = rt.basis_from_pose(target, moved, [finger, hip_joint])
    np.testing.assert_allclose(local, np.broadcast_to(basis[[finger, hip_joint]], local.shape), atol=1e-9)


def test_fingers_both_rigs_have_turn_as_the_source_fingers_do():
    """The index fingers and thumbs (named so in both rigs) take the source's world rotation change: on a
    scaled copy with other rolls they turn exactly as the source's do, and they are the bones carried."""
    source = cmu_rig(WALK)
    target = cmu_rig(WALK, scale=1.1, rolls=0.2)
    pose = source_pose(WALK, source, FRAMES[:20])
    moved = rt.transfer_pose(source, pose, target, np.tile(np.eye(4), (len(target), 1, 1)), np.zeros((20, 3)))
    fingers = [target.names.index(n) for n in ("LeftHandIndex1", "LThumb", "RightHandIndex1", "RThumb")]
    assert rt.carried_bones(source, target) == tuple(sorted(fingers))
    s_change = world_rotations(source, pose)[:, fingers] @ np.swapaxes(world_rotations(source, source.rest[None]),
                                                                       -1, -2)[:, fingers]
    t_change = world_rotations(target, moved)[:, fingers] @ np.swapaxes(world_rotations(target, target.rest[None]),
                                                                        -1, -2)[:, fingers]
    np.testing.assert_allclose(t_change, s_change, atol=1e-9)
    assert np.abs(s_change - np.eye(3)).max() > 0.1  # they do turn


def test_a_clavicle_the_source_lacks_rides_on_the_chest():
    source = cmu_rig(WALK)
    groups = dict(source.groups)
    for side in ("L", "R"):
        groups[f"arm.{side}"] = groups[f"arm.{side}"][1:]  # a source without clavicles
    source = rt.Rig(source.names, source.parents, source.rest, source.lengths, source.connected, groups)
    target = cmu_rig(WALK)
    pairs = {p.target: p for p in rt.pair_bones(source, target)}
    clavicle = target.groups["arm.L"][0]
    assert pairs[clavicle].sources == () and pairs[clavicle].rides_on == target.groups["trunk"][-1]
    pose = source_pose(WALK, source, FRAMES[:30])
    moved = rt.transfer_pose(source, pose, target, np.tile(np.eye(4), (len(target), 1, 1)), np.zeros((30, 3)))
    chest = target.groups["trunk"][-1]
    relation = np.linalg.inv(moved[:, chest]) @ moved[:, clavicle]
    np.testing.assert_allclose(relation, np.broadcast_to(np.linalg.inv(target.rest[chest]) @ target.rest[clavicle],
                                                         relation.shape), atol=1e-9)


# ---------------------------------------------------------------------------------------------------------
# Contacts and targets


def test_intervals_bridge_short_gaps_and_drop_short_runs():
    mask = np.zeros(40, dtype=bool)
    mask[2:10] = mask[12:20] = True  # a 2-frame gap: one contact
    mask[30:32] = True  # too short
    assert rt.intervals(mask, min_length=4, max_gap=2) == [(2, 20)]
    assert rt.intervals(mask, min_length=4, max_gap=1) == [(2, 10), (12, 20)]


def test_a_step_is_found_as_two_plants():
    settings = rt.RetargetSettings(fps=FPS)
    frames = 120
    x = np.concatenate([np.zeros(40), np.linspace(0.0, 0.6, 40), np.full(40, 0.6)])
    z = 0.08 + np.concatenate([np.zeros(40), 0.15 * np.sin(np.linspace(0, np.pi, 40)), np.zeros(40)])
    ankle = np.stack([x, np.zeros(frames), z], axis=1)
    found = rt.detect_contacts("foot.L", ankle[:, None], 0.08, None, 0.9, settings)
    assert [c.kind for c in found] == [rt.GROUND, rt.GROUND]
    runs = sorted((c.start, c.stop) for c in found)
    (a0, b0), (a1, b1) = runs
    assert a0 == 0 and b1 == frames
    # The plants end and start where the foot is still moving slower than the threshold towards one neighbouring
    # frame at least: the frame it comes to rest on, and the one it leaves from, are the plant's.
    steps = np.linalg.norm(np.diff(ankle, axis=0), axis=1) * FPS
    speed = np.minimum(np.concatenate([steps[:1], steps]), np.concatenate([steps, steps[-1:]]))
    limit = settings.detection.plant_speed * 0.9
    assert np.all(speed[a0:b0] < limit) and np.all(speed[a1:b1] < limit)
    assert speed[b0] >= limit and speed[a1 - 1] >= limit
    assert 38 <= b0 <= 41 and 79 <= a1 <= 82


def test_holds_are_still_inside_and_blend_without_a_jump():
    free = np.stack([np.linspace(0, 1, 100), np.zeros(100), np.zeros(100)], axis=1)
    held_point = np.array([0.3, 0.1, 0.0])
    blend = 8
    out = rt.hold(free, [(30, 50, held_point)], blend)
    np.testing.assert_array_equal(out[30:50], np.broadcast_to(held_point, (20, 3)))
    np.testing.assert_array_equal(out[:30 - blend - 1], free[:30 - blend - 1])
    np.testing.assert_array_equal(out[50 + blend + 1:], free[50 + blend + 1:])
    # Smoothstep over blend+1 frames of the offset from the free trajectory where the hold begins or ends: a
    # step at most 1.5/(blend+1) of that offset more than the free step, however far the free trajectory
    # runs from the held point meanwhile.
    jump = max(np.linalg.norm(held_point - free[30]), np.linalg.norm(held_point - free[49]))
    steps = np.linalg.norm(np.diff(out, axis=0), axis=1)
    assert steps.max() <= 1.5 * jump / (blend + 1) + np.linalg.norm(free[1] - free[0]) + 1e-12


def test_a_hold_approached_fast_is_entered_no_faster_than_its_offset_allows():
    """A hand swinging up fast onto a bar held a little aside: before the hold it keeps the free motion and
    moves at most 1.5/(blend+1) of the offset at the hold's first frame faster than it."""
    frames = 60
    free = np.zeros((frames, 3))
    free[:, 2] = np.minimum(np.arange(frames), 30) * 0.05  # 5 cm a frame up to the bar at frame 30
    bar = free[30] + np.array([0.12, 0.0, 0.02])
    blend = 6
    out = rt.hold(free, [(30, 45, bar)], blend)
    np.testing.assert_array_equal(out[30:45], np.broadcast_to(bar, (15, 3)))
    extra = np.linalg.norm(np.diff(out - free, axis=0), axis=1)
    assert extra.max() <= 1.5 * np.linalg.norm(bar - free[30]) / (blend + 1) + 1e-12


def test_overlapping_holds_blend_continuously():
    free = np.zeros((60, 3))
    out = rt.hold(free, [(10, 25, np.array([1.0, 0, 0])), (28, 40, np.array([0.0, 1.0, 0]))], 6)
    steps = np.linalg.norm(np.diff(out, axis=0), axis=1)
    assert steps.max() < 0.5  # the two held points are 1.41 apart: no frame jumps between them


@settings(deadline=None, max_examples=30)
@given(arrays(np.float64, (40, 2), elements=st.floats(-1.0, 1.0)), st.integers(0, 6))
def test_moving_average_is_the_windowed_mean(values, half_width):
    out = rt.moving_average(values, half_width)
    padded = np.concatenate([np.repeat(values[:1], half_width, 0), values, np.repeat(values[-1:], half_width, 0)])
    expected = np.array([padded[f:f + 2 * half_width + 1].mean(axis=0) for f in range(len(values))])
    np.testing.assert_allclose(out, expected, atol=1e-12)


def test_body_shift_brings_every_target_within_reach_and_only_where_needed():
    """Four limbs on a body bobbing up and down: targets drift out of reach now and then. After the shift
    every target is within reach (less the settle margin); frames far from any such moment are not moved,
    and the shift changes gently from frame to frame."""
    frames = 200
    t = np.arange(frames)
    body = np.stack([0.2 * np.sin(t / 15.0), np.zeros(frames), 0.05 * np.sin(t / 7.0)], axis=1)
    offsets = np.array([[0.2, 0, 0.5], [-0.2, 0, 0.5], [0.1, 0, 0], [-0.1, 0, 0]])
    bases = body[:, None] + offsets
    reach = np.array([0.6, 0.6, 0.9, 0.9])
    feet = np.array([[0.1, 0.0, -0.85], [-0.1, 0.0, -0.85]])  # planted, about at full stretch
    hands = offsets[:2] + np.array([[0.45, 0.2, 0.0], [-0.45, 0.2, 0.0]])
    targets = np.concatenate([np.broadcast_to(hands, (frames, 2, 3)) + 0.15 * np.sin(t / 10.0)[:, None, None],
                              np.broadcast_to(feet, (frames, 2, 3))], axis=1)
    margin, settle, half = 0.03, 0.015, 6
    shift = rt.body_shift(bases, targets, reach, [2, 2, 3, 3], margin, settle, half)
    distance = np.linalg.norm(targets - bases - shift[:, None], axis=-1)
    assert np.all(distance <= (1 - settle) * reach + 1e-9)
    needed = np.any(np.linalg.norm(targets - bases, axis=-1) > (1 - margin) * reach, axis=1)
    assert needed.any() and not needed.all()
    quiet = ~np.convolve(needed, np.ones(2 * half + 1), mode="same").astype(bool)
    assert quiet.any()
    np.testing.assert_array_equal(shift[quiet], 0.0)
    steps = np.linalg.norm(np.diff(shift, axis=0), axis=1)
    target_steps = np.linalg.norm(np.diff(targets - bases, axis=0), axis=-1).max()
    assert steps.max() <= 2 * target_steps


def test_body_shift_goes_where_it_is_asked_to_as_far_as_reach_allows_and_no_faster_than_told():
    """A body whose held hands and feet all sit 0.2 aside of where its limbs hold them: asked to move that
    far, the body does so exactly where every target stays within reach from there; where that would leave
    the hands out of reach it stops short (within reach less the settle margin); and however suddenly
    the asked-for shift changes, the shift changes by at most ``max_step`` a frame (the clip being long
    enough to spread the change)."""
    frames = 120
    bases = np.broadcast_to(np.array([[0.2, 0, 0.5], [-0.2, 0, 0.5], [0.1, 0, 0], [-0.1, 0, 0]]), (frames, 4, 3))
    reach = np.array([0.6, 0.6, 0.9, 0.9])
    aside = np.array([0.2, 0.0, 0.0])
    targets = bases + np.array([[0.0, 0.3, 0.0], [0.0, 0.3, 0.0], [0.0, 0.0, -0.5], [0.0, 0.0, -0.5]]) + aside
    wanted = np.where((np.arange(frames) < 60)[:, None], aside, 6 * aside)  # then far beyond the hands' reach
    margin, settle, half = 0.03, 0.015, 3
    free = rt.body_shift(bases, targets, reach, [2, 2, 3, 3], margin, settle, half, preferred=wanted)
    np.testing.assert_allclose(free[:60 - 2 * half], np.broadcast_to(aside, (60 - 2 * half, 3)), atol=1e-12)
    distance = np.linalg.norm(targets - bases - free[:, None], axis=-1)
    assert np.all(distance <= (1 - settle) * reach + 1e-9)
    assert np.linalg.norm(free[-1] - wanted[-1]) > 0.1  # stopped short of the far shift
    limited = rt.body_shift(bases, targets, reach, [2, 2, 3, 3], margin, settle, half, max_step=0.01,
                            preferred=wanted)
    assert np.linalg.norm(np.diff(limited, axis=0), axis=1).max() <= 0.01
    assert np.linalg.norm(np.diff(free, axis=0), axis=1).max() > 0.01  # the asked-for shift jumps


def test_body_shift_is_held_back_by_fixed_targets_but_not_by_those_that_ride_on_it():
    """Held feet that ask the body 0.15 up while the hands' targets hang near full stretch below the shoulders:
    taken as fixed in the world, the hands keep the body down (within their reach less the margin); marked as
    riding on the shift (free trajectories, which move with the body), they bound nothing and the body goes
    the whole way. Held targets bound it either way."""
    frames = 40
    bases = np.broadcast_to(np.array([[0.2, 0, 0.5], [-0.2, 0, 0.5], [0.1, 0, 0], [-0.1, 0, 0]]), (frames, 4, 3))
    reach = np.array([0.6, 0.6, 0.9, 0.9])
    targets = bases + np.array([[0.0, 0.0, -0.58], [0.0, 0.0, -0.58], [0.0, 0.1, -0.6], [0.0, -0.1, -0.6]])
    up = np.broadcast_to(np.array([0.0, 0.0, 0.15]), (frames, 3))
    margin, settle, half = 0.03, 0.015, 3
    riding = np.zeros((frames, 4), dtype=bool)
    riding[:, :2] = True
    fixed = rt.body_shift(bases, targets, reach, [2, 2, 3, 3], margin, settle, half, preferred=up)
    assert np.all(fixed[:, 2] < 0.15 - 0.1)
    hands = np.linalg.norm(targets[:, :2] - bases[:, :2] - fixed[:, None], axis=-1)
    assert np.all(hands <= (1 - settle) * reach[:2] + 1e-9)
    free = rt.body_shift(bases, targets, reach, [2, 2, 3, 3], margin, settle, half, preferred=up, riding=riding)
    np.testing.assert_allclose(free, up, atol=1e-12)
    far = targets.copy()
    far[:, 2:, 2] -= 0.3  # the feet held lower than the legs reach from there: the held ones still bound the shift
    held = rt.body_shift(bases, far, reach, [2, 2, 3, 3], margin, settle, half, preferred=up, riding=riding)
    feet = np.linalg.norm(far[:, 2:] - bases[:, 2:] - held[:, None], axis=-1)
    assert np.all(feet <= (1 - settle) * reach[2:] + 1e-9) and np.all(held[:, 2] < 0.0)


@given(arrays(np.float64, st.integers(1, 40), elements=st.floats(0.0, 0.3)), st.floats(0.001, 0.05))
@settings(max_examples=60, deadline=None)
def test_a_raised_foot_is_let_down_no_faster_than_the_blend(lift, step):
    """The foot's lift over the floor after rise.let_go: at least what the floor asks on every frame, falling by at
    most ``step`` a frame, and the least such lift (on each frame some earlier frame's lift, less ``step`` per
    frame since, is exactly it)."""
    from fullbody_adjust.solver.retarget.rise import let_go as _let_go

    out = _let_go(lift, step)
    assert np.all(out >= lift - 1e-12)
    assert np.all(np.diff(out) >= -step - 1e-12)
    since = np.arange(len(lift))[:, None] - np.arange(len(lift))[None, :]
    cone = np.where(since >= 0, lift[None, :] - step * since, -np.inf).max(axis=1)
    np.testing.assert_allclose(out, cone, atol=1e-12)
    spike = np.zeros(10)
    spike[3] = 0.122  # KayKit's toe-off: the clamp lets go at once; the lift comes down over frames
    np.testing.assert_allclose(_let_go(spike, 0.02)[3:10], np.maximum(0.122 - 0.02 * np.arange(7), 0.0))


# ---------------------------------------------------------------------------------------------------------
# The plan


def plan_for(clip_name, target, frames, **settings):
    source = cmu_rig(clip_name)
    pose = source_pose(clip_name, source, frames)
    plan = rt.plan_retarget(source, pose, target, np.tile(np.eye(4), (len(target), 1, 1)),
                            rt.RetargetSettings(fps=FPS, **{k: v for k, v in settings.items() if k != "boxes"}),
                            settings.get("boxes"))
    return source, pose, plan


def pivot_steps(points):
    """(n-1,) horizontal steps of the foot's stillest point (the one it turns about, of world points
    (n,P,3)) to the next frame."""
    return np.linalg.norm(np.diff(points[..., :2], axis=0), axis=-1).min(axis=1)


def planned_foot_points(target, plan, effector):
    """The target's foot points (F,P,3) as planned: the ankle and the sole (the heads of the foot's bones, no
    leaf tail) of the transferred foot, moved so its ankle is on the target."""
    points = rt.effector_points(target, plan.start_pose, effector)
    return points - points[:, :1] + plan.world_targets[:, rt.EFFECTORS.index(effector), None]


def test_planted_feet_are_held_still_and_free_effectors_follow_the_transferred_pose():
    """Walk onto other proportions: the point a planted foot turns about (heel, ball, toes) does not move;
    the lowest point of each foot is on the floor while planted and never below it; the hands (no contact
    objects) are exactly where the start pose (the source's rotations carried over, the body shifted as the
    plan shifts it) puts the wrists, so the solve leaves the arms as the source holds them."""
    target = cmu_rig(WALK, scale=0.85, group_scales={"leg.L": 1.1, "leg.R": 1.1}, rolls=0.1)
    source, pose, plan = plan_for(WALK, target, np.arange(1, 317))
    t_heads = world_heads(target, plan.start_pose)
    assert plan.leg_ratio == pytest.approx(rt.leg_length(target) / rt.leg_length(source))
    for k, effector in enumerate(("hand.L", "hand.R")):
        np.testing.assert_allclose(plan.world_targets[:, k], t_heads[:, target.groups[effector][0]], atol=1e-12)
    planted = 0
    for effector in ("foot.L", "foot.R"):
        points = planned_foot_points(target, plan, effector)
        lowest = points[..., 2].min(axis=1)
        assert lowest.min() >= plan.ground - 1e-12
        for a, b in plan.contact_intervals[effector]:
            assert pivot_steps(points[a:b]).max() < 1e-12
            np.testing.assert_allclose(lowest[a:b], plan.ground, atol=1e-12)
            planted += b - a
    assert planted > 0.5 * len(plan.contacts)  # a walk: each foot planted a good part of the time
    assert not plan.contacts[:, :2].any()  # hands never touch the ground here


def test_a_run_of_short_stances_is_planted_at_any_frame_rate():
    """The walk played 2.5 times as fast (every other and a half frame: a stance of a few frames, as a
    run's) at 30 frames per second: each foot is still found planted, on about the same share of frames."""
    target = cmu_rig(WALK, scale=1.2)
    slow = plan_for(WALK, target, np.arange(1, 317))[2]
    source = cmu_rig(WALK)
    pose = source_pose(WALK, source, np.arange(1, 317, 10))  # 12 fps of the clip's time
    fast = rt.plan_retarget(source, pose, target, np.tile(np.eye(4), (len(target), 1, 1)),
                            rt.RetargetSettings(fps=30.0))
    for k in (2, 3):
        assert len(fast.contact_intervals[rt.EFFECTORS[k]]) >= 2
        assert fast.contacts[:, k].mean() > 0.5 * slow.contacts[:, k].mean()


def test_a_foot_still_above_the_floor_stands_on_something_raised():
    """The walk with its second half lifted 0.3 (a step up): plants up there are raised contacts, held at
    their own height (the source foot's lowest point there, on average), the soles on it."""
    source = cmu_rig(WALK)
    frames = np.arange(1, 317)
    pose = source_pose(WALK, source, frames)
    lowest = np.min([rt.effector_points(source, pose, e)[..., 2].min(axis=1)
                     for e in ("foot.L", "foot.R")], axis=0)
    pose[len(frames) // 2:, :, 2, 3] += 0.3 / np.linalg.norm(source.matrix_world[:3, 0])
    target = cmu_rig(WALK, scale=1.2)
    plan = rt.plan_retarget(source, pose, target, np.tile(np.eye(4), (len(target), 1, 1)), rt.RetargetSettings(fps=FPS))
    raised = [c for e in ("foot.L", "foot.R") for c in plan.contact_list[e] if c.kind == rt.RAISED]
    assert len(raised) >= 2
    for c in raised:
        assert c.start >= len(frames) // 2 - 1
        own = rt.effector_points(source, pose, c.effector)[c.start:c.stop, :, 2].min(axis=1)
        assert c.surface == pytest.approx(own.mean(), abs=1e-12)
        assert c.surface == pytest.approx(lowest.min() + 0.3, abs=0.1)
        points = planned_foot_points(target, plan, c.effector)[c.start:c.stop]
        np.testing.assert_allclose(points[..., 2].min(axis=1), c.surface, atol=1e-12)
    grounded = [c for e in ("foot.L", "foot.R") for c in plan.contact_list[e] if c.kind == rt.GROUND]
    assert grounded and all(c.stop <= len(frames) // 2 + 1 for c in grounded)


def test_a_raised_support_out_of_a_small_targets_scale_is_scaled_with_the_motion():
    """The same step up 0.3 onto a target a third the size: held at the source's world height, its feet would
    stand on a step as high as its own legs are long (the body lifted, the legs stretched), so the support,
    inferred from the source alone, is scaled with the motion about the floor, as far above it as the target's
    own feet go there; the contact says that height and the planned soles rest on it."""
    source = cmu_rig(WALK)
    frames = np.arange(1, 317)
    pose = source_pose(WALK, source, frames)
    pose[len(frames) // 2:, :, 2, 3] += 0.3 / np.linalg.norm(source.matrix_world[:3, 0])
    target = cmu_rig(WALK, scale=0.3)
    plan = rt.plan_retarget(source, pose, target, np.tile(np.eye(4), (len(target), 1, 1)), rt.RetargetSettings(fps=FPS))
    floor = rt.source_floor(source, pose)
    raised = [c for e in ("foot.L", "foot.R") for c in plan.contact_list[e] if c.kind == rt.RAISED]
    assert len(raised) >= 2
    for c in raised:
        own = rt.effector_points(source, pose, c.effector)[c.start:c.stop, :, 2].min(axis=1).mean()
        assert c.surface == pytest.approx(floor + plan.leg_ratio * (own - floor), abs=1e-12)
        assert c.surface < floor + 0.5 * (own - floor)  # not the source's world height
        points = planned_foot_points(target, plan, c.effector)[c.start:c.stop]
        np.testing.assert_allclose(points[..., 2].min(axis=1), c.surface, atol=1e-12)


def test_raised_supports_are_scaled_together_when_one_is_out_of_scale():
    """The walk onto a step 0.3 up, then onto one 1.0 up, retargeted onto a target 0.6 times the size: the high
    step alone is out of its scale (its world and scaled heights more than half a target leg apart), and the
    supports are one structure: both scaled with the motion, so the higher step stays the higher for the target
    (the low one kept at its world height would stand above where the scaled motion puts it)."""
    source = cmu_rig(WALK)
    frames = np.arange(1, 317)
    pose = source_pose(WALK, source, frames)
    third = len(frames) // 3
    unit = np.linalg.norm(source.matrix_world[:3, 0])
    pose[third:2 * third, :, 2, 3] += 0.3 / unit
    pose[2 * third:, :, 2, 3] += 1.0 / unit
    target = cmu_rig(WALK, scale=0.6)
    plan = rt.plan_retarget(source, pose, target, np.tile(np.eye(4), (len(target), 1, 1)), rt.RetargetSettings(fps=FPS))
    floor = rt.source_floor(source, pose)
    leg = rt.leg_length(target)
    raised = [c for e in ("foot.L", "foot.R") for c in plan.contact_list[e] if c.kind == rt.RAISED]
    owns = [rt.effector_points(source, pose, c.effector)[c.start:c.stop, :, 2].min(axis=1).mean() for c in raised]
    low = [own for own in owns if own < floor + 0.6]
    assert low and len(low) < len(owns)  # plants on both steps
    assert all((1.0 - plan.leg_ratio) * (own - floor) <= 0.5 * leg for own in low)  # the low step: within scale
    for c, own in zip(raised, owns):
        assert c.surface == pytest.approx(floor + plan.leg_ratio * (own - floor), abs=1e-12)


def test_a_turned_target_keeps_its_own_heading():
    """The target object turned 90° about Z: its motion is the source's turned the same way (the hips'
    path relative to its start, turned), not the source's world direction."""
    source = cmu_rig(WALK)
    frames = np.arange(1, 200)
    pose = source_pose(WALK, source, frames)
    straight = cmu_rig(WALK, scale=1.2)
    turn = np.eye(4)
    turn[:3, :3] = [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]
    turned = rt.Rig(straight.names, straight.parents, straight.rest, straight.lengths, straight.connected,
                    straight.groups, turn @ straight.matrix_world)
    identity = np.tile(np.eye(4), (len(straight), 1, 1))
    settings = rt.RetargetSettings(fps=FPS)
    a = rt.plan_retarget(source, pose, straight, identity, settings)
    b = rt.plan_retarget(source, pose, turned, identity, settings)
    hips_a = rt.hip_centres(straight, straight.world_points(a.start_pose)[0])
    hips_b = rt.hip_centres(turned, turned.world_points(b.start_pose)[0])
    travel = hips_a[-1] - hips_a[0]
    assert np.linalg.norm(travel[:2]) > 0.5
    np.testing.assert_allclose(hips_b - hips_b[0], (hips_a - hips_a[0]) @ turn[:3, :3].T, atol=1e-9)


def test_object_contacts_go_to_the_source_positions_on_the_object():
    """Climb: both hands hold a bar. A box around where the source's hands rest: the target's wrists go
    exactly to the source's (mean) positions there (with exact=False, to the scaled ones), and move there
    and away without a jump although the scaled path is far from the bar."""
    source = cmu_rig(CLIMB)
    frames = np.arange(1, 1201, 2)
    pose = source_pose(CLIMB, source, frames)
    wrists = world_heads(source, pose)[:, [source.groups["hand.L"][0], source.groups["hand.R"][0]]]
    speed = np.linalg.norm(np.gradient(wrists, axis=0), axis=-1) * FPS / 2
    still = np.nonzero((speed < 0.1).all(axis=1))[0]
    assert len(still) > 20
    bar = wrists[still].reshape(-1, 3)
    boxes = (bar.min(axis=0)[None] - 0.02, bar.max(axis=0)[None] + 0.02)
    target = cmu_rig(CLIMB, scale=1.2)
    loose = rt.plan_retarget(source, pose, target, np.tile(np.eye(4), (len(target), 1, 1)),
                             rt.RetargetSettings(fps=FPS / 2, exact=False), boxes)
    exact = rt.plan_retarget(source, pose, target, np.tile(np.eye(4), (len(target), 1, 1)),
                             rt.RetargetSettings(fps=FPS / 2), boxes)
    leg = rt.leg_length(target)
    for k, effector in enumerate(("hand.L", "hand.R")):
        runs = exact.contact_intervals[effector]
        assert runs, effector
        assert all(c.kind == rt.OBJECT for c in exact.contact_list[effector])
        for a, b in runs:
            np.testing.assert_allclose(exact.world_targets[a:b, k], np.broadcast_to(
                wrists[a:b, k].mean(axis=0), (b - a, 3)), atol=1e-12)
            a_s, a_t = anchors(source, target, loose.ground)
            scaled = scaled_about(wrists[a:b, k], a_s, a_t, loose.leg_ratio).mean(axis=0)
            np.testing.assert_allclose(loose.world_targets[a:b, k], np.broadcast_to(scaled, (b - a, 3)), atol=1e-12)
        steps = np.linalg.norm(np.diff(exact.world_targets[:, k], axis=0), axis=1)
        s_steps = np.linalg.norm(np.diff(wrists[:, k], axis=0), axis=1)
        assert np.all(steps <= 1.2 * s_steps + 1.6 * 1.5 * leg / (FPS / 2))


def test_bad_plans_are_clear_errors():
    source = cmu_rig(WALK)
    target = cmu_rig(WALK)
    identity = np.tile(np.eye(4), (len(target), 1, 1))
    with pytest.raises(SolverInputError, match="source pose must have shape"):
        rt.plan_retarget(source, np.zeros((3, 2, 4, 4)), target, identity)
    pose = source_pose(WALK, source, [5, 6])
    pose[0, 3, 0, 0] = np.nan
    with pytest.raises(SolverInputError, match="NaN"):
        rt.plan_retarget(source, pose, target, identity)
    with pytest.raises(SolverInputError, match="fps"):
        rt.RetargetSettings(fps=0)
    with pytest.raises(SolverInputError, match="plant_speed"):
        rt.RetargetSettings(detection=rt.ContactDetection(plant_speed=-1.0))
    with pytest.raises(SolverInputError, match="detection"):
        rt.RetargetSettings(detection={"plant_speed": 0.3})


def test_motion_limits_fix_each_hinge_in_its_upper_bone():
    """The elbow and knee hinge axes are one fixed direction in the upper arm's / thigh's frame on every
    frame, the bend axis of the clearly bent frames: those bend positively about it."""
    target = cmu_rig(WALK, scale=1.1, rolls=0.3)
    _, _, plan = plan_for(WALK, target, np.arange(1, 181))
    model, bones = rt.body_model(target)
    start, heads, tails = plan.start_pose[:, bones], plan.heads[:, bones], plan.tails[:, bones]
    limits = rt.motion_limits(model, start, heads, tails)
    for name in ("arm.L", "arm.R", "leg.L", "leg.R"):
        limb = model.limbs[name]
        hinge = len(limb.bones) - 1
        axes = limits[name].limits.hinge_axis[:, hinge]
        upper = start[:, limb.bones[hinge - 1], :3, :3]
        local = np.einsum("fji,fj->fi", upper / np.linalg.norm(upper, axis=-2, keepdims=True), axes)
        np.testing.assert_allclose(local, np.broadcast_to(local[0], local.shape), atol=1e-12)
        joints = limb.joints(heads, tails)
        u, v = joints[:, hinge] - joints[:, hinge - 1], joints[:, hinge + 1] - joints[:, hinge]
        bend = np.cross(u, v)
        bent = angle_between(u, v) > 0.2
        assert bent.any(), name
        assert np.all(np.sum(bend[bent] * axes[bent], axis=1) > 0.0)


# ---------------------------------------------------------------------------------------------------------
# The whole numpy path: plan -> adjust_frames -> channels


def retarget_numpy(clip_name, target, frames):
    source, pose, plan = plan_for(clip_name, target, frames)
    model, bones = rt.body_model(target)
    start, heads, tails = plan.start_pose[:, bones], plan.heads[:, bones], plan.tails[:, bones]
    result = adjust_frames(model, heads, tails, plan.targets, rt.EFFECTORS, [2, 2, 3, 3],
                           limits=rt.motion_limits(model, start, heads, tails))
    return source, pose, plan, result, rt.solved_pose(plan, result.rotations, result.heads, bones)


@pytest.mark.parametrize("clip_name", [WALK, PICKUP])
def test_retargeted_motion_reaches_keeps_plants_and_adds_no_pops(clip_name):
    """Another body: legs 1.15, arms 0.9, trunk 1.2 times the source's, bones rolled, arms in an A-pose."""
    target = cmu_rig(clip_name, scale=1.1, rolls=0.3, arm_drop=np.radians(30),
                     group_scales={"leg.L": 1.15, "leg.R": 1.15, "arm.L": 0.9, "arm.R": 0.9, "trunk": 1.2})
    frames = np.arange(1, 181)
    source, pose, plan, result, solved = retarget_numpy(clip_name, target, frames)
    tolerance = 1e-4 * rt.leg_length(target)
    assert np.all(result.residuals <= tolerance)


    # No new pops: the largest change of velocity of any joint, and of angular velocity of any bone, is about
    # the source's own (positions relative to each rig's leg length).
    s_body, t_body = mapped(source), mapped(target)
    s_rough = rt.roughness(world_heads(source, pose)[:, s_body], rt.leg_length(source)).max()
    t_rough = rt.roughness(world_heads(target, solved)[:, t_body], rt.leg_length(target)).max()
    assert t_rough <= 1.5 * s_rough
    s_turn = rt.angular_roughness(world_rotations(source, pose)[:, s_body]).max()
    t_turn = rt.angular_roughness(world_rotations(target, solved)[:, t_body]).max()
    assert t_turn <= 1.5 * s_turn

    # The channels written back reproduce the solved pose through forward kinematics.
    basis = np.tile(np.eye(4), (len(frames), len(target), 1, 1))
    basis[:, t_body] = rt.basis_from_pose(target, solved, t_body)
    np.testing.assert_allclose(rt.forward_kinematics(target, basis)[:, t_body], solved[:, t_body], atol=1e-9)

    # Planted feet do not slide in the result either (toes and heels where the written channels put them).
    written = rt.forward_kinematics(target, basis)
    for effector in ("foot.L", "foot.R"):
        points = rt.effector_points(target, written, effector)  # ankle and sole
        for a, b in plan.contact_intervals[effector]:
            assert pivot_steps(points[a:b]).sum() <= 2 * tolerance


# ---------------------------------------------------------------------------------------------------------
# Contact figures


def test_contact_figures_measure_error_sliding_floor_and_pops():
    """A foot planted over frames 10-30 that slides 0.03 along x and hovers 0.01 above the floor, dips 0.02
    below it on frames 40-44, and jumps 0.5 at frame 50; a hand 0.04 from a box while touching it."""
    frames = 60
    foot = np.zeros((frames, 2, 3))
    foot[:, 1, 0] = 0.2  # the toes, 0.2 ahead of the ankle, both at the same height
    foot[:, :, 2] = 0.01
    foot[10:30, :, 0] += np.linspace(0.0, 0.03, 20)[:, None]  # dragged: 0.03 in all
    foot[40:45, :, 2] = -0.02
    foot[50:, :, 0] += 0.5
    hand = np.zeros((frames, 1, 3))
    hand[:, 0] = [0.0, 0.0, 1.04]
    boxes = (np.array([[-0.1, -0.1, 0.9]]), np.array([[0.1, 0.1, 1.0]]))
    contacts = {"foot.L": [rt.Contact("foot.L", 10, 30, rt.GROUND, 0.0)],
                "hand.L": [rt.Contact("hand.L", 5, 25, rt.OBJECT, float("nan"), 0)]}
    still_source = {"foot.L": np.zeros_like(foot), "hand.L": np.broadcast_to([0.0, 0.0, 1.0], hand.shape)}
    figures, curves = rt.contact_figures(contacts, {"foot.L": foot, "hand.L": hand}, still_source, boxes, 0.0,
                                         leg=1.0, ratio=1.0, fps=30.0)
    f = figures["foot.L"]
    assert f["contact_frames"] == 20 and f["contact_error"]["max"] == pytest.approx(0.01)
    assert f["sliding"]["max"] == pytest.approx(0.03)
    assert f["frames_below_floor"] == 5 and f["deepest_below_floor"] == pytest.approx(0.02)
    # Steps faster than the (still) source's by 1.5 leg/s at 30 fps (0.05 per frame): the jump, not the dip.
    steps = np.r_[0.0, np.linalg.norm(np.diff(foot[:, 0], axis=0), axis=1)]
    assert f["pops"] == int(np.sum(steps > 0.05)) == 1 and f["largest_step"] == pytest.approx(0.5)
    assert f["not_held_frames"] == 0  # 0.01 off: within the hold tolerance
    h = figures["hand.L"]
    assert h["contact_error"]["max"] == pytest.approx(0.04) and h["frames_below_floor"] == 0
    assert h["not_held_frames"] == 20  # the source touches it (distance 0): 0.04 is not held
    assert np.isnan(curves["hand.L"][:5]).all() and np.isfinite(curves["hand.L"][5:25]).all()
