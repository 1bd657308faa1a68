"""Rigs, targets and exact measurements for the operator tests (test_adjust_pose.py, test_bad_input.py).

Everything here reads Blender data the way a user would see it: the evaluated pose after a depsgraph update,
the target empties' world matrices, and the F-Curves that actually animate the armature (legacy
``action.fcurves`` on 4.2, the assigned slot's channelbag on 4.4+).
"""

import re

import addon_utils
import bpy
import numpy as np

from fullbody_adjust.bridge.writing.channels import armature_rotations_to_channels
from fullbody_adjust.solver.maths.geometry import affine_inverse
from tests.helpers.blender_data import bone_map, bulk, evaluated  # noqa: F401 (bone_map: for the tests)
from tests.helpers.bvh import CMU_SCALE, MOCAP_DIR

CMU_CLIP = MOCAP_DIR / "cmu_07_01_walk.bvh"
RIG_KINDS = ("basic", "full", "cmu")
LAYERED_ACTIONS = bpy.app.version >= (4, 4, 0)

# The operator's INFO report, e.g. "3 of 4 targets met, largest residual 1.2e-07; 13 bones keyed".
REPORT = re.compile(r"(\d+) of (\d+) targets met(?: over \d+ frames)?, largest residual ([-+.e\d]+(?:inf|nan)?)")


def world_rotations_to_channels(obj, snapshot, new_world, bones):
    """armature_rotations_to_channels of world matrices ((k,4,4), (F,k,4,4) for a batched snapshot): the tests
    ask for world matrices under every object transform, the bridge converts armature-space ones."""
    to_armature = affine_inverse(snapshot.matrix_world)
    return armature_rotations_to_channels(
        obj, snapshot, (to_armature[:, None] if snapshot.batched else to_armature) @ np.asarray(new_world), bones)


def add_rig(kind):
    """A rig in the current scene, active and selected: the Rigify basic (29 bones) or full (159 bones)
    human metarig, or the CMU walk clip imported with Blender's BVH importer (31 bones, 1 unit = CMU_SCALE m)."""
    if kind == "cmu":
        addon_utils.enable("io_anim_bvh", default_set=True)
        bpy.ops.import_anim.bvh(filepath=str(CMU_CLIP), global_scale=CMU_SCALE)
    else:
        bpy.ops.preferences.addon_enable(module="rigify")
        {"basic": bpy.ops.object.armature_basic_human_metarig_add,
         "full": bpy.ops.object.armature_human_metarig_add}[kind]()
    obj = bpy.context.active_object
    assert obj is not None and obj.type == 'ARMATURE'
    return obj


def add_single_bone_armature(name="Stick", bones=1):
    """An armature of one chain of `bones` bones going up (nothing in it looks like a body)."""
    data = bpy.data.armatures.new(name)
    obj = bpy.data.objects.new(name, data)
    bpy.context.scene.collection.objects.link(obj)
    bpy.context.view_layer.objects.active = obj
    bpy.ops.object.mode_set(mode='EDIT')
    parent = None
    for i in range(bones):
        bone = data.edit_bones.new(f"Bone.{i:03d}")
        bone.head, bone.tail = (0.0, 0.0, 0.5 * i), (0.0, 0.0, 0.5 * (i + 1))
        bone.parent, bone.use_connect = parent, parent is not None
        parent = bone
    bpy.ops.object.mode_set(mode='OBJECT')
    return obj


def slot(obj, effector):
    return next(s for s in obj.fullbody_adjust.targets if s.effector == effector)


def place(target, position):
    """Move a target empty so its world location is `position` (see Pose.to_world)."""
    matrix = target.matrix_world.copy()
    matrix.translation = tuple(float(x) for x in position)
    target.matrix_world = matrix


# --- the evaluated pose ---------------------------------------------------------------------------------------


def add_box(obj, location, size):
    """A cube mesh of edge ``size`` centred at ``location`` (world), ``obj`` active again (an obstacle)."""
    bpy.ops.mesh.primitive_cube_add(size=size, location=tuple(location))
    box = bpy.context.active_object
    bpy.context.view_layer.objects.active = obj
    return box


def inside_box(box, points):
    """(n,) bool: which world ``points`` (n,3) lie in the box mesh's world bounds."""
    corners = np.array([box.matrix_world @ v.co for v in box.data.vertices])
    lo, hi = corners.min(axis=0), corners.max(axis=0)
    return np.all((points >= lo) & (points <= hi), axis=1)


class Pose:
    """The evaluated pose: per bone heads, tails and matrices in armature space, and heads in the world."""

    def __init__(self, obj):
        ev = evaluated(obj)
        self.names = [pb.name for pb in ev.pose.bones]
        self.index = {name: i for i, name in enumerate(self.names)}
        self.matrix_world = np.array(ev.matrix_world, dtype=np.float64)
        self.heads = bulk(ev.pose.bones, "head", (3,))
        self.tails = bulk(ev.pose.bones, "tail", (3,))
        self.matrices = bulk(ev.pose.bones, "matrix", (4, 4)).transpose(0, 2, 1)  # foreach_get is column-major
        self.world_heads = self.to_world(self.heads)

    def to_world(self, points):
        return np.asarray(points) @ self.matrix_world[:3, :3].T + self.matrix_world[:3, 3]

    def head(self, bone):
        """Armature-space head of `bone`."""
        return self.heads[self.index[bone]]

    def tail(self, bone):
        return self.tails[self.index[bone]]

    @property
    def lengths(self):
        """Armature-space bone lengths (the rig's own lengths, whatever the object's scale)."""
        return np.linalg.norm(self.tails - self.heads, axis=1)

    def height(self):
        """The rig's extent along its own up axis (armature Z), in world units."""
        up = self.matrix_world[:3, 2] / np.linalg.norm(self.matrix_world[:3, 2])
        points = self.to_world(np.concatenate([self.heads, self.tails])) @ up
        return float(points.max() - points.min())


def effector_bone(obj, effector):
    """The bone whose head is the effector joint: the hand/foot bone, the last bone of the head group."""
    return bone_map(obj)[effector][-1]


def chain_joints(obj, pose, group):
    """Armature-space joints of a chain group (as solver/body/model.py builds them): the heads of its bones plus the wrist or ankle (head
    of the hand/foot bone) for a limb, the tail of the last bone (the SC) for the trunk."""
    groups = bone_map(obj)
    bones = groups[group]
    end = {"arm.L": "hand.L", "arm.R": "hand.R", "leg.L": "foot.L", "leg.R": "foot.R"}.get(group)
    last = pose.head(groups[end][0]) if end else pose.tail(bones[-1])
    return np.array([pose.head(b) for b in bones] + [last])


def body_joints(obj, pose):
    """Armature-space joints of every chain (trunk, arms, legs), wrists and ankles included."""
    return np.concatenate([chain_joints(obj, pose, g) for g in ("trunk", "arm.L", "arm.R", "leg.L", "leg.R")])


def chain_length(joints):
    return float(np.linalg.norm(np.diff(joints, axis=0), axis=1).sum())


def residuals(obj, pose=None):
    """{effector: world distance from its joint to its target} for every enabled slot."""
    pose = pose or Pose(obj)
    out = {}
    for s in obj.fullbody_adjust.targets:
        if s.enabled and s.target is not None:
            goal = np.array(evaluated(s.target).matrix_world.translation)
            out[s.effector] = float(np.linalg.norm(pose.to_world(pose.head(effector_bone(obj, s.effector))) - goal))
    return out


def body_axes(obj, pose):
    """Armature-space (up, left, forward) unit vectors of the character: armature Z is up (Rigify and the BVH
    importer both build Z-up armatures), left from the shoulder joints (the upper arms' heads: CMU's clavicles
    share one head)."""
    up = np.array([0.0, 0.0, 1.0])
    left = pose.head(bone_map(obj)["arm.L"][-2]) - pose.head(bone_map(obj)["arm.R"][-2])
    left = left - up * (left @ up)
    left /= np.linalg.norm(left)
    return up, left, np.cross(left, up)


def parse_report(text):
    """(met, tasks, largest residual) from captured output holding the operator's INFO report."""
    found = REPORT.findall(text)
    assert found, f"no adjust report in output: {text[-500:]!r}"
    met, tasks, largest = found[-1]
    return int(met), int(tasks), float(largest)


# --- exact state ----------------------------------------------------------------------------------------------


def animating_fcurves(obj):
    """The F-Curves that animate `obj`: action.fcurves before 4.4, the assigned slot's channelbag after."""
    anim = obj.animation_data
    if anim is None or anim.action is None:
        return []
    if not LAYERED_ACTIONS:
        return list(anim.action.fcurves)
    if anim.action_slot is None:
        return []
    from bpy_extras import anim_utils

    channelbag = anim_utils.action_get_channelbag_for_slot(anim.action, anim.action_slot)
    return list(channelbag.fcurves) if channelbag is not None else []


_KEY_ENUMS = ("interpolation", "handle_left_type", "handle_right_type", "easing", "type")


def fcurve_state(fcurve):
    """Everything about an F-Curve's keys, as exact bytes (bit-for-bit comparable)."""
    points = fcurve.keyframe_points
    n = len(points)
    state = {"group": fcurve.group.name if fcurve.group else None, "extrapolation": fcurve.extrapolation,
             "modifiers": len(fcurve.modifiers), "mute": fcurve.mute}
    for prop in ("co", "handle_left", "handle_right"):
        buffer = np.empty(2 * n, dtype=np.float32)
        points.foreach_get(prop, buffer)
        state[prop] = buffer.reshape(n, 2).tobytes()
    for prop in ("amplitude", "back", "period"):
        buffer = np.empty(n, dtype=np.float32)
        points.foreach_get(prop, buffer)
        state[prop] = buffer.tobytes()
    for prop in _KEY_ENUMS:
        state[prop] = tuple(getattr(p, prop) for p in points)
    return state


def keys_state(obj):
    """{(data_path, index): fcurve_state} of the F-Curves animating `obj`."""
    return {(fc.data_path, fc.array_index): fcurve_state(fc) for fc in animating_fcurves(obj)}


def keys_at(fcurve, frame):
    co = np.empty(2 * len(fcurve.keyframe_points), dtype=np.float32)
    fcurve.keyframe_points.foreach_get("co", co)
    return np.nonzero(np.abs(co[0::2] - frame) < 0.01)[0]


def drop_frame(state, frame):
    """A copy of an fcurve_state without its keys at `frame` (for comparing the keys on other frames)."""
    co = np.frombuffer(state["co"], dtype=np.float32).reshape(-1, 2)
    keep = np.abs(co[:, 0] - frame) >= 0.01
    out = dict(state)
    for prop in ("co", "handle_left", "handle_right"):
        out[prop] = np.frombuffer(state[prop], dtype=np.float32).reshape(-1, 2)[keep].tobytes()
    for prop in ("amplitude", "back", "period"):
        out[prop] = np.frombuffer(state[prop], dtype=np.float32)[keep].tobytes()
    for prop in _KEY_ENUMS:
        out[prop] = tuple(v for v, k in zip(state[prop], keep) if k)
    return out


def without_derived_handles(state):
    """A copy of an fcurve_state whose handle positions are kept only where the user owns them (FREE and
    ALIGNED handles): Blender recomputes AUTO, AUTO_CLAMPED and VECTOR handles from the neighbouring keys
    whenever a key is added, as its own keyframe insertion does."""
    out = dict(state)
    for side in ("handle_left", "handle_right"):
        handles = np.frombuffer(state[side], dtype=np.float32).reshape(-1, 2).copy()
        derived = np.array([kind not in ('FREE', 'ALIGNED') for kind in state[f"{side}_type"]], dtype=bool)
        handles[derived] = np.nan
        out[side] = handles.tobytes()
    return out


_CHANNELS = ("location", "rotation_quaternion", "rotation_euler", "rotation_axis_angle", "scale")


def pose_channels(obj):
    """{bone: (rotation_mode, channel values...)} exactly as stored on the pose bones."""
    return {pb.name: (pb.rotation_mode,) + tuple(tuple(getattr(pb, c)) for c in _CHANNELS) for pb in obj.pose.bones}


def settings_state(obj):
    settings = obj.fullbody_adjust
    return {
        "targets": [(s.effector, s.target.name if s.target else None, s.priority, s.enabled)
                    for s in settings.targets],
        "bone_map": [(item.group, item.bone) for item in settings.bone_map],
        "obstacles": settings.obstacles.name if settings.obstacles else None,
        "options": tuple(getattr(settings, name) for name in
                         ("variant", "margin", "tolerance", "max_iterations", "use_joint_limits",
                          "keep_hand_orientation")),
    }


def file_state():
    """What a bad input must leave alone: every object (transform, parent, pose as set and as evaluated, keys,
    settings), the actions, the collections and the current frame."""
    objects = {}
    for ob in bpy.data.objects:
        entry = {"type": ob.type, "library": ob.library.name if ob.library else None,
                 "matrix_basis": np.array(ob.matrix_basis).tobytes(),  # bytes: NaN == NaN
                 "parent": ob.parent.name if ob.parent else None, "scenes": tuple(s.name for s in ob.users_scene),
                 "action": (ob.animation_data.action.name if ob.animation_data and ob.animation_data.action
                            else None)}
        if ob.type == 'ARMATURE':
            entry.update(pose=pose_channels(ob), evaluated=Pose(ob).matrices.tobytes(), keys=keys_state(ob),
                         settings=settings_state(ob))
        objects[ob.name] = entry
    return {"objects": objects, "actions": sorted(a.name for a in bpy.data.actions),
            "collections": sorted(c.name for c in bpy.data.collections),
            "frame": (bpy.context.scene.frame_current, bpy.context.scene.frame_subframe)}


def key_bones(obj, bone_names, frame, channels=("location", "rotation"), *, action_name=None):
    """Key the current values of ``channels`` ('location', 'rotation' — the property of each bone's rotation
    mode —, 'scale') of the pose bones ``bone_names`` at scene ``frame`` through the extension's keyframes
    module; returns the action written to."""
    from fullbody_adjust.bridge.writing.keyframes import key_bones_frames
    from fullbody_adjust.solver.vocabulary import ROTATION_PROPERTY

    values = {}
    for name in bone_names:
        pose_bone = obj.pose.bones.get(name)
        if pose_bone is None:
            return key_bones_frames(obj, bone_names, [frame], values, action_name=action_name)  # its one-line error
        props = [ROTATION_PROPERTY[pose_bone.rotation_mode] if kind == "rotation" else kind for kind in channels]
        values[name] = {prop: np.array(getattr(pose_bone, prop), dtype=np.float64)[None] for prop in props}
    return key_bones_frames(obj, bone_names, [frame], values, action_name=action_name)


def swing_world_matrices(snapshot, bones, old_dirs, new_dirs, new_heads):
    """New world matrices (..., k, 4, 4) for ``bones`` of a PoseSnapshot: each bone's old rotation turned by the
    minimal swing taking its segment's old direction to the new one (twist kept), its head moved to
    ``new_heads``, its scale unchanged; the swing taken in armature space, so the result is reachable under any
    object scale. old_dirs, new_dirs, new_heads: (k,3), or (F,k,3) for a batched snapshot."""
    from fullbody_adjust.solver.maths.geometry import swing_rotation

    idx = snapshot.indices(bones)
    to_armature = np.linalg.inv(snapshot.matrix_world)[..., None, :, :]
    linear_inv = to_armature[..., :3, :3]

    def apply(matrix, vectors):
        return np.einsum("...ij,...j->...i", matrix, np.asarray(vectors, dtype=np.float64))

    swing = swing_rotation(apply(linear_inv, old_dirs), apply(linear_inv, new_dirs))
    old = snapshot.pose_matrices[..., idx, :, :]
    new = np.zeros(old.shape)
    new[..., :3, :3] = swing @ old[..., :3, :3]
    new[..., :3, 3] = apply(linear_inv, new_heads) + to_armature[..., :3, 3]
    new[..., 3, 3] = 1.0
    return snapshot.matrix_world[..., None, :, :] @ new
