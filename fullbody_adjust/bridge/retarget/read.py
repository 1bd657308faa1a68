"""Reading what a retarget needs from Blender (see bridge/retarget/run.py): each armature as a solver.retarget.Rig,
the source's motion (from its action's F-Curves when they alone move the bones, else frame by frame), its bone
map, frame range and the contact objects' boxes. Nothing here changes Blender data."""

import re
from dataclasses import replace

import numpy as np

from ...solver.retarget import motion as rt
from ...solver.body.joint_ends import joint_ends
from ..rig import control_rig, mapping
from ..writing import keyframes
from ..reading import pose
from ..errors import AdjustError
from .soles import mesh_soles

_BONE_PATH = re.compile(r'^pose\.bones\["((?:[^"\\]|\\.)*)"\]\.(\w+)$')
_SAME_FRAME = 1e-4  # a key this close to a frame is at it (keys are float32)


def read_motion(obj, rig, frames):
    """The armature's pose at ``frames`` (``rig`` = its solver.retarget.Rig): (pose matrices (F,J,4,4) in the
    space of the returned world matrix (4,4), how it was read). From the action's F-Curves when they alone
    move the bones, else frame by frame."""
    if _why_not_fcurves(obj) is None:
        basis = _basis_from_fcurves(obj, frames)
        return rt.forward_kinematics(rig, basis), np.array(obj.matrix_world, dtype=np.float64), "F-Curves"
    snapshot = pose.read_pose_frames(obj, frames)
    world = snapshot.matrix_world
    # One world matrix for all frames: the motion of an animated object goes into the pose matrices.
    relative = np.linalg.inv(world[0])[None] @ world
    return relative[:, None] @ snapshot.pose_matrices, world[0].copy(), "frame by frame"


def _why_not_fcurves(obj):
    """None when the action's F-Curves alone give the pose (the fast path is exact), else why not."""
    anim = obj.animation_data
    if anim is None or anim.action is None:
        return "no action"
    if anim.use_tweak_mode or (anim.use_nla and any(not t.mute and len(t.strips) for t in anim.nla_tracks)):
        return "NLA tracks"
    if len(anim.drivers):
        return "drivers"
    if abs(anim.action_influence - 1.0) > 0.0:
        return "action influence"
    if obj.parent is not None or any(c.enabled for c in obj.constraints):
        return "the object is parented or constrained"
    for fc in keyframes.animating_fcurves(obj):
        if not fc.data_path.startswith("pose.bones["):
            return "the action animates more than bones"
    for pb in obj.pose.bones:
        if any(c.enabled and c.influence > 0.0 for c in pb.constraints):
            return "bone constraints"
    for bone in obj.data.bones:
        if (not bone.use_inherit_rotation or bone.inherit_scale != 'FULL' or not bone.use_local_location
                or bone.use_relative_parent):
            return "bones that do not inherit plainly"
    return None


def _basis_from_fcurves(obj, frames):
    """matrix_basis (F,J,4,4) from the action's F-Curves at ``frames``; unanimated channels keep the pose
    bones' current values."""
    pose_bones = obj.pose.bones
    names = [pb.name for pb in pose_bones]
    index = {n: i for i, n in enumerate(names)}
    modes = pose.rotation_modes(obj)
    count, frames_n = len(names), len(frames)
    used = {"location", "scale"} | {rt.ROTATION_PROPERTY[m] for m in modes}
    values = {prop: np.broadcast_to(pose_property(pose_bones, prop, (size,)), (frames_n, count, size)).copy()
              for prop, size in pose.CHANNEL_SIZES.items() if prop in used}
    lookup = {}  # curves keyed on the same frames (a BVH import keys every frame) share one key search
    for fc in keyframes.animating_fcurves(obj):
        match = _BONE_PATH.match(fc.data_path)
        if match is None or fc.mute or (fc.group is not None and fc.group.mute):
            continue
        bone = index.get(match.group(1).replace('\\"', '"').replace("\\\\", "\\"))
        prop = match.group(2)
        if bone is None or prop not in values or not 0 <= fc.array_index < values[prop].shape[2]:
            continue
        if prop.startswith("rotation_") and rt.ROTATION_PROPERTY[modes[bone]] != prop:
            continue  # the bone rotates by another property: this curve has no effect
        values[prop][:, bone, fc.array_index] = _evaluate(fc, frames, lookup)
    if len(set(modes)) == 1:  # one rotation mode throughout (as imports make): no gathering by mode
        rotation = rt.rotation_matrices(modes[0], values[rt.ROTATION_PROPERTY[modes[0]]])
    else:
        rotation = np.empty((frames_n, count, 3, 3))
        for mode in set(modes):
            bones = [i for i, m in enumerate(modes) if m == mode]
            rotation[:, bones] = rt.rotation_matrices(mode, values[rt.ROTATION_PROPERTY[mode]][:, bones])
    return rt.basis_matrices(values["location"], rotation, values["scale"])


def _evaluate(fcurve, frames, lookup):
    """The F-Curve at ``frames``: key values where keys sit on the frames (Blender returns exactly those),
    F-Curve.evaluate elsewhere and whenever modifiers may change the curve. ``lookup`` caches the key search
    by key frames."""
    points = fcurve.keyframe_points
    n = len(points)
    if n == 0 or any(not m.mute for m in fcurve.modifiers):
        return np.array([fcurve.evaluate(float(f)) for f in frames])
    co = np.empty(2 * n, dtype=np.float32)
    points.foreach_get("co", co)
    x = co[0::2]
    key = x.tobytes()
    search = lookup.get(key)
    if search is None:
        order = np.argsort(x, kind="stable") if np.any(np.diff(x) < 0.0) else None
        ordered = (x if order is None else x[order]).astype(np.float64)
        at = np.clip(np.searchsorted(ordered, frames - _SAME_FRAME), 0, n - 1)
        on_key = np.abs(ordered[at] - frames) <= _SAME_FRAME
        between = np.nonzero(~on_key)[0]
        # A key on every frame, in a row (a BVH import keys every frame): the values are one slice.
        run = int(at[0]) if (order is None and between.size == 0 and len(at)
                             and np.array_equal(at, np.arange(at[0], at[0] + len(at)))) else None
        search = lookup[key] = (order, at, on_key, between, run)
    order, at, on_key, between, run = search
    y = co[1::2]
    if run is not None:
        return y[run:run + len(frames)].astype(np.float64)
    y = y.astype(np.float64)
    if order is not None:
        y = y[order]
    out = np.where(on_key, y[at], 0.0)
    for i in between:
        out[i] = fcurve.evaluate(float(frames[i]))
    return out


def pose_property(collection, prop, shape):
    size = int(np.prod(shape))
    buffer = np.empty(len(collection) * size, dtype=np.float32)
    collection.foreach_get(prop, buffer)
    return buffer.reshape((len(collection),) + shape).astype(np.float64)


def rig_of(obj, bone_map):
    """solver.retarget.Rig of an armature object, its groups from ``bone_map``: each bone's joint end
    (solver.joint_ends, from the rest matrices and rest tails) and each foot's sole from the meshes the
    armature deforms (bridge/retarget/soles; the foot's joints where there is none). A control rig's Rig is
    its mapped skeleton alone (control_rig), in the metarig's hierarchy: the controls are posed from it."""
    if control_rig.is_generated_rigify(obj):
        return _skeleton_rig(obj, bone_map)
    bones = obj.data.bones
    names = tuple(b.name for b in bones)
    index = {n: i for i, n in enumerate(names)}
    parents = pose.parent_indices(bones)
    if any(p >= i for i, p in enumerate(parents)):
        raise AdjustError(f"Armature '{obj.name}': a bone is listed before its parent")
    connected = np.array([b.use_connect for b in bones], dtype=bool)
    groups = {g: tuple(index[b] for b in members) for g, members in bone_map.groups.items()}
    rest = pose_property(bones, "matrix_local", (4, 4)).transpose(0, 2, 1)
    return rt.Rig(names=names, parents=parents, rest=rest, lengths=pose_property(bones, "length", ()),
                  connected=connected, groups=groups, matrix_world=np.array(obj.matrix_world, dtype=np.float64),
                  ends=joint_ends(parents, rest, pose_property(bones, "tail_local", (3,)), groups),
                  soles=mesh_soles(obj, names, parents, groups, rest))


def _skeleton_rig(obj, bone_map):
    """The Rig of a control rig's mapped bones, parents first in the metarig's hierarchy."""
    all_names = tuple(b.name for b in obj.data.bones)
    all_parents = control_rig.skeleton_parents(all_names, pose.parent_indices(obj.data.bones))
    mapped = [bone for _group, bone in bone_map.items()]
    depth = {}

    def depth_of(i):
        if i not in depth:
            depth[i] = 0 if all_parents[i] < 0 else depth_of(int(all_parents[i])) + 1
        return depth[i]

    order = sorted((all_names.index(b) for b in mapped), key=depth_of)
    local = {i: k for k, i in enumerate(order)}

    def mapped_parent(i):  # the nearest mapped ancestor in the metarig's hierarchy
        j = int(all_parents[i])
        while j >= 0 and j not in local:
            j = int(all_parents[j])
        return local.get(j, -1)

    bones = [obj.data.bones[all_names[i]] for i in order]
    names = tuple(b.name for b in bones)
    groups = {g: tuple(names.index(b) for b in members) for g, members in bone_map.groups.items()}
    parents = np.array([mapped_parent(i) for i in order], dtype=np.int64)
    rest = np.array([np.array(b.matrix_local) for b in bones], dtype=np.float64)
    return rt.Rig(names=names, parents=parents, rest=rest,
                  lengths=np.array([b.length for b in bones], dtype=np.float64),
                  connected=np.array([b.use_connect for b in bones], dtype=bool), groups=groups,
                  matrix_world=np.array(obj.matrix_world, dtype=np.float64),
                  ends=joint_ends(parents, rest, np.array([tuple(b.tail_local) for b in bones]), groups),
                  soles=mesh_soles(obj, names, parents, groups, rest))


def with_world(rig, world):
    return replace(rig, matrix_world=world)


def source_map(obj):
    """The source's bone map, without storing anything on it (the source is never changed): its stored map when
    it fits, else detection's, but a map the user typed is checked and never replaced (mapping.read_map)."""
    return mapping.read_map(obj)


def check_source(obj):
    if obj is None:
        raise AdjustError("No source armature: select the armature whose motion to retarget")
    if obj.type != 'ARMATURE':
        raise AdjustError(f"Source '{obj.name}' is not an armature")
    if obj.mode == 'EDIT':
        raise AdjustError(f"Source '{obj.name}' is in Edit Mode: leave it to read its motion")
    anim = obj.animation_data
    if anim is None or (anim.action is None and not any(len(t.strips) for t in anim.nla_tracks)):
        raise AdjustError(f"Source '{obj.name}' has no animation to retarget")


def frame_range(source_obj, frame_start, frame_end):
    action = source_obj.animation_data.action
    if frame_start is None or frame_end is None:
        if action is None:
            raise AdjustError(f"Source '{source_obj.name}' has no action: give the frame range")
        lo, hi = action.frame_range
        frame_start = int(round(lo)) if frame_start is None else frame_start
        frame_end = int(round(hi)) if frame_end is None else frame_end
    if int(frame_end) < int(frame_start):
        raise AdjustError(f"Frame range {frame_start}..{frame_end} is empty")
    return np.arange(int(frame_start), int(frame_end) + 1, dtype=np.float64)


def contact_boxes(context, objects):
    """World bounding boxes (mins, maxs) (K,3) of the contact objects, as evaluated."""
    depsgraph = context.evaluated_depsgraph_get()
    mins, maxs = [], []
    for obj in objects:
        evaluated = obj.evaluated_get(depsgraph)
        world = np.array(evaluated.matrix_world, dtype=np.float64)
        corners = np.array([tuple(c) for c in evaluated.bound_box], dtype=np.float64)
        if len(corners) == 0:
            raise AdjustError(f"Contact object '{obj.name}' has no extent")
        points = corners @ world[:3, :3].T + world[:3, 3]
        mins.append(points.min(axis=0))
        maxs.append(points.max(axis=0))
    return np.array(mins), np.array(maxs)
