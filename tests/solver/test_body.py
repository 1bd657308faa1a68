"""The body model (paper §5.1) built from bone descriptions, its default limits, and the BVH test helper."""

import math

import numpy as np
import pytest

from fullbody_adjust.solver.body.model import BodyModel
from fullbody_adjust.solver.limits.human import HumanLimits, default_limits
from fullbody_adjust.solver.errors import SolverInputError
from fullbody_adjust.solver.maths.geometry import swing_rotation
from fullbody_adjust.solver.limits.joint_limits import CONE, HINGE, JointLimits, hinge_twist
from tests.helpers.bvh import CMU_CLIPS, CMU_GROUPS, read_bvh, read_cmu


@pytest.fixture(scope="module")
def walk():
    return read_cmu("cmu_07_01_walk.bvh")


@pytest.fixture(scope="module")
def cmu_model(walk):
    return BodyModel.from_description(walk.names, walk.parents, CMU_GROUPS)


def _angle(a, b):
    a = a / np.linalg.norm(a, axis=-1, keepdims=True)
    b = b / np.linalg.norm(b, axis=-1, keepdims=True)
    return np.arccos(np.clip(np.sum(a * b, axis=-1), -1.0, 1.0))


# ---------------------------------------------------------------------------------------------------------
# BVH helper


def test_bvh_forward_kinematics_follows_the_declared_channel_order(tmp_path):
    # Two joints; the root turns by Z then X (declared "Zrotation Xrotation Yrotation"), the child sits at
    # offset (0, 2, 0). FK: child = root_pos + Rz(a) @ Rx(b) @ Ry(c) @ offset, composed here by hand.
    text = """HIERARCHY
ROOT A
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
  JOINT B
  {
    OFFSET 0 2 0
    CHANNELS 3 Zrotation Xrotation Yrotation
    End Site
    {
      OFFSET 0 0 3
    }
  }
}
MOTION
Frames: 1
Frame Time: 0.01
1 2 3 90 90 0 0 0 0
"""
    path = tmp_path / "two.bvh"
    path.write_text(text)
    clip = read_bvh(path, scale=0.5)
    heads, tails = clip.bones()
    rz = np.array([[0, -1, 0], [1, 0, 0], [0, 0, 1.0]])  # 90 deg about Z
    rx = np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0.0]])  # 90 deg about X
    root = np.array([1, 2, 3.0]) * 0.5
    child = root + rz @ rx @ np.array([0, 2, 0.0]) * 0.5
    np.testing.assert_allclose(heads[0, 0], root, atol=1e-12)
    np.testing.assert_allclose(heads[0, 1], child, atol=1e-12)
    # The root has one child: its tail is that child; the child's tail is its End Site, turned the same way.
    np.testing.assert_allclose(tails[0, 0], child, atol=1e-12)
    np.testing.assert_allclose(tails[0, 1], child + rz @ rx @ np.array([0, 0, 3.0]) * 0.5, atol=1e-12)


def test_bvh_reader_rejects_a_truncated_motion_section(tmp_path):
    path = tmp_path / "bad.bvh"
    path.write_text("HIERARCHY\nROOT A\n{\nOFFSET 0 0 0\nCHANNELS 3 Xposition Yposition Zposition\n}\n"
                    "MOTION\nFrames: 2\nFrame Time: 0.1\n1 2 3\n")
    with pytest.raises(ValueError, match="MOTION has 3 values"):
        read_bvh(path)


def test_cmu_bones_have_positive_length_and_keep_it_over_the_clip(walk):
    heads, tails = walk.bones(np.arange(0, walk.frame_count, 25))
    lengths = np.linalg.norm(tails - heads, axis=-1)
    assert lengths.min() > 0.005  # coincident children got Blender's +0.1 unit nudge
    np.testing.assert_allclose(lengths, lengths[:1].repeat(len(lengths), 0), rtol=1e-9)


# ---------------------------------------------------------------------------------------------------------
# Body model


def test_cmu_groups_give_the_papers_chains(walk, cmu_model):
    heads, tails = walk.bones([5])
    idx = {n: i for i, n in enumerate(walk.names)}
    m = cmu_model
    assert set(m.limbs) == {"trunk", "arm.L", "arm.R", "leg.L", "leg.R", "head"}
    trunk = m.limbs["trunk"].joints(heads, tails)[0]
    np.testing.assert_array_equal(trunk[0], heads[0, idx["LowerBack"]])
    np.testing.assert_array_equal(trunk[-1], tails[0, idx["Spine1"]])  # the SC
    np.testing.assert_array_equal(m.sc(heads, tails)[0], trunk[-1])
    arm = m.limbs["arm.L"].joints(heads, tails)[0]
    np.testing.assert_array_equal(arm[0], heads[0, idx["LeftShoulder"]])
    np.testing.assert_array_equal(arm[-1], heads[0, idx["LeftHand"]])  # the wrist
    leg = m.limbs["leg.R"].joints(heads, tails)[0]
    np.testing.assert_array_equal(leg[-1], heads[0, idx["RightFoot"]])  # the ankle
    head = m.limbs["head"].joints(heads, tails)[0]
    np.testing.assert_array_equal(head[-1], heads[0, idx["Head"]])
    assert m.effectors == ("hand.L", "hand.R", "foot.L", "foot.R", "head")
    # Parents come before children in the propagation order.
    pos = np.empty(len(m.order), dtype=int)
    pos[m.order] = np.arange(len(m.order))
    assert all(pos[p] < pos[j] for j, p in enumerate(m.parents) if p >= 0)


def test_head_group_of_one_bone_has_no_head_effector(walk):
    groups = dict(CMU_GROUPS, head=["Head"])
    m = BodyModel.from_description(walk.names, walk.parents, groups)
    assert "head" not in m.limbs and "head" not in m.effectors


@pytest.mark.parametrize("change, message", [
    (lambda g: g.update(hips=["Hips"]), "unknown group 'hips'"),
    (lambda g: g.pop("leg.R"), "group 'leg.R' is missing"),
    (lambda g: g.update({"hand.L": ["NoSuchBone"]}), "no bone named 'NoSuchBone'"),
    (lambda g: g.update({"hand.L": ["LeftHand", "LeftFingerBase"]}), "exactly one bone"),
    (lambda g: g.update({"arm.L": ["LeftArm"]}), "at least 2 bones"),
    (lambda g: g.update({"arm.L": ["LeftForeArm", "LeftArm"]}), "not in parent -> child order"),
    (lambda g: g.update({"hand.L": ["RightHand"], "hand.R": ["LeftHand"]}), "hand.L must end arm.L"),
    (lambda g: g.update({"head": ["Neck", "Spine"]}), "'Spine' is in both"),
    (lambda g: g.update({"leg.L": ["LeftArm", "LeftForeArm"], "arm.L": ["LeftShoulder", "LeftArm"]}),
     "is in both"),
    (lambda g: g.update({"trunk": []}), "group 'trunk' is empty"),
])
def test_bad_groups_are_rejected_with_a_reason(walk, change, message):
    groups = {k: list(v) for k, v in CMU_GROUPS.items()}
    change(groups)
    with pytest.raises(SolverInputError, match=message):
        BodyModel.from_description(walk.names, walk.parents, groups)


def test_legs_must_not_hang_from_the_trunk():
    names = ["pelvis", "spine", "chest", "clav.L", "up.L", "lo.L", "hand.L", "clav.R", "up.R", "lo.R", "hand.R",
             "thigh.L", "shin.L", "foot.L", "thigh.R", "shin.R", "foot.R"]
    parents = [-1, 0, 1, 2, 3, 4, 5, 2, 7, 8, 9, 1, 11, 12, 0, 14, 15]  # thigh.L under the spine
    groups = {"root": ["pelvis"], "trunk": ["spine", "chest"], "arm.L": ["clav.L", "up.L", "lo.L"],
              "hand.L": ["hand.L"], "arm.R": ["clav.R", "up.R", "lo.R"], "hand.R": ["hand.R"],
              "leg.L": ["thigh.L", "shin.L"], "foot.L": ["foot.L"], "leg.R": ["thigh.R", "shin.R"],
              "foot.R": ["foot.R"]}
    with pytest.raises(SolverInputError, match="leg.L must hang from the root, not from trunk bone 'spine'"):
        BodyModel.from_description(names, parents, groups)


@pytest.mark.parametrize("names, parents, message", [
    (["a", "a"], [-1, 0], "'a' appears twice"),
    (["a", "b"], [-1, 5], "invalid parent index 5"),
    (["a", "b", "c"], [2, 0, 1], "parent cycle"),
    (["a", "b"], [-1, 0.5], "parents must be integers"),
    ([], [], "no bones"),
])
def test_bad_hierarchies_are_rejected(names, parents, message):
    with pytest.raises(SolverInputError, match=message):
        BodyModel.from_description(names, parents, CMU_GROUPS)


# ---------------------------------------------------------------------------------------------------------
# Default limits


@pytest.mark.parametrize("clip", CMU_CLIPS)
def test_captured_poses_satisfy_the_default_limits(clip):
    """The defaults were chosen from these clips: every sampled captured pose must lie within its own
    limits, measured here from the joint positions (cones: angle to the parent direction; hinges: bend about
    the axis within range and the limb in the hinge plane)."""
    c = read_cmu(clip)
    m = BodyModel.from_description(c.names, c.parents, CMU_GROUPS)
    heads, tails = c.bones(np.arange(1, c.frame_count, 9))
    limits = default_limits(m, heads, tails)
    for name, limb in m.limbs.items():
        joints = limb.joints(heads, tails)
        segs = joints[:, 1:] - joints[:, :-1]
        ll = limits[name]
        for i, kind in enumerate(ll.limits.kind):
            parent = ll.parent_direction if i == 0 else segs[:, i - 1]
            if kind == CONE:
                assert np.all(_angle(parent, segs[:, i]) <= ll.limits.cone_angle[i] + 1e-9), (clip, name, i)
            elif kind == HINGE:
                axis = ll.limits.hinge_axis[:, i]
                u = parent / np.linalg.norm(parent, axis=1, keepdims=True)
                v = segs[:, i] / np.linalg.norm(segs[:, i], axis=1, keepdims=True)
                np.testing.assert_allclose(np.sum(axis * u, axis=1), 0.0, atol=1e-9)
                # In the hinge plane turned by no more than the hinge's twist range (a slight bend far off the
                # body's plane is noise: the axis stays the body's), but for limbs straight to 1e-3 rad.
                turned = np.abs(hinge_twist(u, v, axis))
                bent = np.linalg.norm(np.cross(u, v), axis=1) > math.sin(1e-3)
                assert np.all(turned[bent] <= ll.limits.hinge_twist[i] + 1e-9), (clip, name)
                bend = np.arctan2(np.sum(np.cross(u, v) * axis, axis=1), np.sum(u * v, axis=1))
                assert np.all(bend >= ll.limits.hinge_min[i] - 1e-9) and np.all(bend <= ll.limits.hinge_max[i])


def test_straight_limb_hinge_follows_the_bone_x_axis_else_the_body_frame(walk, cmu_model):
    heads, tails = walk.bones([0])  # frame 1: the T-pose, arms straight out to the sides
    idx = {n: i for i, n in enumerate(walk.names)}
    arm = cmu_model.limbs["arm.L"].joints(heads, tails)[0]
    upper = arm[2] - arm[1]
    fore = arm[3] - arm[2]
    assert _angle(upper, fore) < HumanLimits().bent
    up, left, forward = cmu_model.body_frame(heads, tails)
    # Heuristic: the elbow bends forward, so the axis is upper x forward (normalised).
    expected = np.cross(upper, forward[0])
    expected /= np.linalg.norm(expected)
    axis = default_limits(cmu_model, heads, tails)["arm.L"].limits.hinge_axis[0, 2]
    assert np.dot(axis, expected) > 0.999
    # A given bone X axis (any sign) overrides it; the sign is matched to the natural bend side.
    x_axes = np.zeros((len(walk.names), 3))
    x_axes[:] = [1.0, 0.0, 0.0]
    x_axes[idx["LeftForeArm"]] = -up[0]  # the rig says this elbow bends about "down": i.e. sideways-forward
    axis_x = default_limits(cmu_model, heads, tails, bone_x_axes=x_axes)["arm.L"].limits.hinge_axis[0, 2]
    want = -up[0] - np.dot(-up[0], upper) / np.dot(upper, upper) * upper
    want /= np.linalg.norm(want)
    want *= np.sign(np.dot(want, expected))
    np.testing.assert_allclose(axis_x, want, atol=1e-9)


def test_bent_limb_hinge_is_the_start_bend_plane(walk, cmu_model):
    heads, tails = walk.bones([100])
    leg = cmu_model.limbs["leg.L"].joints(heads, tails)[0]
    thigh, shin = leg[1] - leg[0], leg[2] - leg[1]
    assert _angle(thigh, shin) > HumanLimits().bent
    axis = default_limits(cmu_model, heads, tails)["leg.L"].limits.hinge_axis[0, 1]
    expected = np.cross(thigh, shin)
    np.testing.assert_allclose(axis, expected / np.linalg.norm(expected), atol=1e-12)
    # and that is the knee's natural side: the shin swings backward (against the body's forward direction)
    _, _, forward = cmu_model.body_frame(heads, tails)
    assert np.dot(np.cross(axis, thigh), forward[0]) < 0.0
    assert math.isclose(np.linalg.norm(axis), 1.0)


def test_elbow_and_knee_hinges_get_the_twist_ranges(walk, cmu_model):
    heads, tails = walk.bones([100])
    human = HumanLimits(elbow_twist=0.9, knee_twist=0.4)
    limits = default_limits(cmu_model, heads, tails, human)
    for name, twist in (("arm.L", 0.9), ("arm.R", 0.9), ("leg.L", 0.4), ("leg.R", 0.4)):
        lim = limits[name].limits
        expected = np.where(lim.kind == HINGE, twist, 0.0)
        assert list(lim.hinge_twist) == list(expected) and np.sum(lim.kind == HINGE) == 1
    for name in ("trunk", "head"):
        assert not np.any(limits[name].limits.hinge_twist)


@pytest.mark.parametrize("bad", [{"shoulder": 3.5}, {"elbow": (0.5, -0.5)}, {"knee_twist": 1.6}])
def test_default_limits_refuse_impossible_human_limits_every_time(walk, cmu_model, bad):
    """The limits' ranges are checked once per set of ranges and kept: a set that fails its check is refused on
    every call, not kept; a good set gives the same limits as JointLimits' own checked construction."""
    heads, tails = walk.bones([100])
    for _ in range(2):
        with pytest.raises(SolverInputError):
            default_limits(cmu_model, heads, tails, HumanLimits(**bad))
    for limb in default_limits(cmu_model, heads, tails).values():
        lim = limb.limits
        checked = JointLimits(lim.kind, lim.cone_angle, lim.hinge_axis, lim.hinge_min, lim.hinge_max,
                              lim.hinge_twist)
        for field in ("kind", "cone_angle", "hinge_axis", "hinge_min", "hinge_max", "hinge_twist"):
            np.testing.assert_array_equal(getattr(lim, field), getattr(checked, field))
            assert not getattr(lim, field).flags.writeable


def test_twist_ranges_cover_most_captured_pose_changes():
    """HumanLimits' elbow and knee twists, measured as its docstring says: from a pose to the pose 60 frames
    later in the same clip, how far the later (clearly bent) limb's bend plane turned about the upper bone
    from the start plane carried by that bone's minimal swing, on its natural side (full azimuth: a plane
    turned past 90 deg counts as turned that far, not as bent backwards). At least 94 % fit the range."""
    human = HumanLimits()
    turned = {"arm": [], "leg": []}
    for name in CMU_CLIPS:
        c = read_cmu(name)
        m = BodyModel.from_description(c.names, c.parents, CMU_GROUPS)
        later = np.arange(61, c.frame_count, 6)
        h0, t0 = c.bones(later - 60)
        h1, t1 = c.bones(later)
        limits = default_limits(m, h0, t0, human)
        for limb in ("arm.L", "arm.R", "leg.L", "leg.R"):
            i = len(m.limbs[limb].bones) - 1
            j0, j1 = m.limbs[limb].joints(h0, t0), m.limbs[limb].joints(h1, t1)
            d0 = j0[:, i] - j0[:, i - 1]
            p = j1[:, i] - j1[:, i - 1]
            p /= np.linalg.norm(p, axis=1, keepdims=True)
            v = j1[:, i + 1] - j1[:, i]
            v /= np.linalg.norm(v, axis=1, keepdims=True)
            axis = np.einsum("fab,fb->fa", swing_rotation(d0, p), limits[limb].limits.hinge_axis[:, i])
            axis -= np.sum(axis * p, axis=1, keepdims=True) * p
            axis /= np.linalg.norm(axis, axis=1, keepdims=True)
            side = np.cross(axis, p)
            azimuth = np.abs(np.arctan2(np.sum(v * axis, axis=1), np.sum(v * side, axis=1)))
            bent = _angle(p, v) > 0.5
            turned[limb[:3]].append(azimuth[bent])
    for group, limit in (("arm", human.elbow_twist), ("leg", human.knee_twist)):
        a = np.concatenate(turned[group])
        assert a.size > 500
        assert np.mean(a <= limit) >= 0.94, (group, np.mean(a <= limit))
