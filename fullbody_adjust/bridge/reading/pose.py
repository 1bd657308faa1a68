"""Pose in: an armature's evaluated pose as world-space numpy arrays.

``read_pose`` / ``read_pose_frames`` give a ``PoseSnapshot`` — per bone (in ``obj.data.bones``
order, parents before children) world heads, tails, 4x4 matrices and lengths, plus what writing needs
(rest matrices, parents, current channel values). Rotations out, the solved transforms turned back into
channels, are ``bridge/writing/channels.py``.
"""

from dataclasses import dataclass, replace

import bpy
import numpy as np

from ..errors import AdjustError
from .frames import step_frames


# Channel properties read per bone, with their sizes.
CHANNEL_SIZES = {"location": 3, "rotation_quaternion": 4, "rotation_euler": 3, "rotation_axis_angle": 4,
                 "scale": 3}


@dataclass(frozen=True, eq=False)
class PoseSnapshot:
    """An armature's evaluated pose, world space, float64. B bones in ``obj.data.bones`` order (parents
    first). Single-frame arrays have the shapes shown; ``read_pose_frames`` adds a leading frame axis F
    to every per-frame field (marked *)."""

    names: tuple  # (B,) bone names
    parents: np.ndarray  # (B,) int, parent's index or -1
    use_connect: np.ndarray  # (B,) bool
    rotation_modes: tuple  # (B,) str, e.g. 'QUATERNION', 'XYZ', 'AXIS_ANGLE'
    rest_matrices: np.ndarray  # (B,4,4) Bone.matrix_local (armature space, rest)
    frame: object  # * float (scene frame + subframe); (F,) array when batched
    matrix_world: np.ndarray  # * (4,4) the object's world matrix
    pose_matrices: np.ndarray  # * (B,4,4) PoseBone.matrix (armature space)
    matrices: np.ndarray  # * (B,4,4) world: matrix_world @ pose_matrices
    heads: np.ndarray  # * (B,3) world
    tails: np.ndarray  # * (B,3) world
    lengths: np.ndarray  # * (B,) world |tail - head|
    channels: dict  # * property -> (B,k): location, rotation_quaternion, rotation_euler, rotation_axis_angle,
    #                   scale, and 'matrix_basis' (B,4,4)

    @property
    def batched(self):
        return self.pose_matrices.ndim == 4

    def index(self, name):
        """Index of bone ``name``; AdjustError when the armature has no such bone."""
        try:
            return self._index_of()[name]
        except KeyError:
            raise AdjustError(f"The armature has no bone named '{name}'") from None

    def indices(self, bones):
        """(k,) int indices for bone names or indices."""
        return np.array([b if isinstance(b, (int, np.integer)) else self.index(b) for b in bones], dtype=int)

    def derived(self, key, make, of=None):
        """``make()``, computed once for this snapshot and ``key`` and then kept with it: for what a solve
        derives from its start pose alone, which Live solves from again and again. ``of``: an object the value
        also depends on (a BodyModel), told apart by identity. Keep plain values and arrays here, never bpy
        data (an edit of the armature frees its bones)."""
        memo = self.__dict__.get("_derived")
        if memo is None:
            memo = {}
            object.__setattr__(self, "_derived", memo)
        kept = memo.get(key)
        if kept is None or kept[0] is not of:
            kept = memo[key] = (of, make())
        return kept[1]

    def _index_of(self):
        return self.derived("names index", lambda: {name: i for i, name in enumerate(self.names)})


def read_pose(obj, static=None):
    """The evaluated pose of armature ``obj`` at the current frame (the caller sets it) as a PoseSnapshot.
    ``static``: the rig's rest data as ``read_static`` gives it, from a caller that keeps it between reads."""
    if static is None:
        static = read_static(obj)
    else:
        _check_readable(obj)
    return PoseSnapshot(**static, **_read_frame(obj))


def evaluated_heads(obj, names):
    """World positions (k,3) of the heads of the bones ``names`` in the evaluated pose at the current frame, as
    read_pose gives them (float32 values, then float64), without reading the whole pose."""
    evaluated = obj.evaluated_get(bpy.context.evaluated_depsgraph_get())
    bones = evaluated.pose.bones
    heads = np.array([tuple(bones[name].head) for name in names], dtype=np.float64).reshape(-1, 3)
    return _to_world(np.array(evaluated.matrix_world, dtype=np.float64), heads)


def read_pose_frames(obj, frames, each_frame=None):
    """A batched PoseSnapshot (leading axis F) of ``obj`` at each of ``frames`` (scene frames, may be
    fractional). Sets each frame in turn and restores the scene's current frame afterwards.
    ``each_frame(row, frame)``, when given, is called at every frame too, so other readers share the pass."""
    frames = np.asarray(frames, dtype=np.float64).reshape(-1)
    if len(frames) == 0 or not np.all(np.isfinite(frames)):
        raise ValueError("read_pose_frames needs at least one finite frame")
    static = read_static(obj)
    rows = []
    for row, frame in step_frames(bpy.context.scene, frames):
        rows.append(_read_frame(obj))
        if each_frame is not None:
            each_frame(row, frame)
    stacked = {key: np.stack([row[key] for row in rows]) for key in rows[0] if key != "channels"}
    stacked["channels"] = {key: np.stack([row["channels"][key] for row in rows]) for key in rows[0]["channels"]}
    stacked["frame"] = frames.copy()
    return PoseSnapshot(**static, **stacked)


def parent_indices(bones):
    """Each of an armature's ``bones`` as its parent's index, -1 for a root. One RNA read of each bone's parent,
    looked up by the bone itself (a bpy struct compares and hashes as the data it wraps): a Live update reads them
    all to know the rig has not changed."""
    bones = bones.values()
    index = {bone: i for i, bone in enumerate(bones)}
    return [index.get(bone.parent, -1) for bone in bones]


def read_static(obj):
    """What a PoseSnapshot holds of the rig besides the pose: bone names, parents, connect flags, rotation
    modes and rest matrices."""
    _check_readable(obj)
    bones = obj.data.bones
    count = len(bones)
    if count == 0:
        raise AdjustError(f"Armature '{obj.name}' has no bones")
    names = tuple(bone.name for bone in bones)
    if tuple(pb.name for pb in obj.pose.bones) != names:
        # Blender keeps both in the same (depth-first) order; the snapshot relies on it.
        raise AdjustError(f"Armature '{obj.name}': pose bones out of step with its bones (enter and leave "
                          f"edit mode to rebuild the pose)")
    parents = np.array(parent_indices(bones), dtype=int)
    if np.any(parents >= np.arange(count)):
        raise AdjustError(f"Armature '{obj.name}': a bone is listed before its parent")
    return {
        "names": names,
        "parents": parents,
        "use_connect": _get(bones, "use_connect", count, (), bool),
        "rotation_modes": rotation_modes(obj),
        "rest_matrices": _get_matrices(bones, "matrix_local", count),
    }


def rest_tails(obj):
    """The bones' rest tails (B,3) in armature space, in ``obj.data.bones`` order (joint_ends reads where each bone
    really ends from them)."""
    bones = obj.data.bones
    return _get(bones, "tail_local", len(bones), (3,))


def rotation_modes(obj):
    """Each pose bone's rotation mode (identifiers, in pose-bone order), read in one bulk call: it is read on
    every Adjust Pose and Live update, and one attribute read per bone costs more than the rest of the read."""
    values = np.empty(len(obj.pose.bones), dtype=np.int32)
    obj.pose.bones.foreach_get("rotation_mode", values)
    return tuple(_ROTATION_MODE_NAMES[v] for v in values.tolist())  # tolist: numpy ints index slowly


def _check_readable(obj):
    if obj is None or obj.type != 'ARMATURE':
        raise AdjustError(f"'{getattr(obj, 'name', obj)}' is not an armature")
    if obj.mode == 'EDIT':
        raise AdjustError(f"Armature '{obj.name}' is in Edit Mode: leave it to read or write the pose")


def _read_frame(obj):
    evaluated = obj.evaluated_get(bpy.context.evaluated_depsgraph_get())
    pose_bones = evaluated.pose.bones
    count = len(pose_bones)
    scene = bpy.context.scene
    matrix_world = np.array(evaluated.matrix_world, dtype=np.float64)
    pose_matrices = _get_matrices(pose_bones, "matrix", count)
    heads = _to_world(matrix_world, _get(pose_bones, "head", count, (3,)))
    tails = _to_world(matrix_world, _get(pose_bones, "tail", count, (3,)))
    channels = {prop: _get(pose_bones, prop, count, (size,)) for prop, size in CHANNEL_SIZES.items()}
    channels["matrix_basis"] = _get_matrices(pose_bones, "matrix_basis", count)
    return {
        "frame": scene.frame_current + scene.frame_subframe,
        "matrix_world": matrix_world,
        "pose_matrices": pose_matrices,
        "matrices": matrix_world @ pose_matrices,
        "heads": heads,
        "tails": tails,
        "lengths": np.linalg.norm(tails - heads, axis=-1),
        "channels": channels,
    }


_ROTATION_MODE_NAMES = {item.value: item.identifier
                        for item in bpy.types.PoseBone.bl_rna.properties["rotation_mode"].enum_items}


def _get(collection, prop, count, shape, dtype=np.float32):
    # float32 buffers: Blender stores these as float32, so the values arrive unrounded; then float64.
    buffer = np.empty(count * int(np.prod(shape, dtype=int)), dtype=dtype)
    collection.foreach_get(prop, buffer)
    return buffer.reshape((count,) + shape).astype(np.float64 if dtype is np.float32 else dtype)


def _get_matrices(collection, prop, count):
    # foreach_get gives matrices column-major.
    return _get(collection, prop, count, (4, 4)).transpose(0, 2, 1).copy()


def _to_world(matrix_world, points):
    return points @ matrix_world[:3, :3].T + matrix_world[:3, 3]


def as_batch(snapshot):
    """A single-frame snapshot as the one-frame batch read_pose_frames would give (the same batch object on
    every call, so what a solve derives from it is kept too)."""
    return snapshot.derived("batch", lambda: replace(
        snapshot, frame=np.array([snapshot.frame]), matrix_world=snapshot.matrix_world[None],
        pose_matrices=snapshot.pose_matrices[None], matrices=snapshot.matrices[None], heads=snapshot.heads[None],
        tails=snapshot.tails[None], lengths=snapshot.lengths[None],
        channels={key: value[None] for key, value in snapshot.channels.items()}))
