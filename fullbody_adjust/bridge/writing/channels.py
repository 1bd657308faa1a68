"""Rotations out: solved armature-space matrices turned back into each pose bone's own channels (location,
rotation in its rotation mode), and written.

The caller gives, for the bones it moved, new matrices in armature space (as PoseBone.matrix: rotation +
translation; the bone's scale unchanged), e.g. the minimal swing of each segment applied to the bone's old
rotation, so twist/roll is kept.
``armature_rotations_to_channels`` converts them top-down with ``Bone.convert_local_to_pose``, never
touching the scene; ``apply_channels`` writes the result. Bones not passed keep their local channels.
A matrix a rigid bone cannot take is reduced to what it can: its head and its direction (Y axis) exactly,
its roll from the requested Z axis, the rig's bone lengths kept. Callers working in world space (the object
moved, rotated or scaled) bring their matrices into armature space first (``snapshot.matrix_world``).

Bone constraints are not evaluated by the conversion: channels are computed as if the moved bones had
none (their evaluated pose is read, but a constraint still acts on the written channels).
"""

import math

import numpy as np
from mathutils import Euler, Matrix, Vector

from ...solver.maths import vectors as gp
from ...solver.maths.geometry import cross, dot, norm
from ...solver.vocabulary import ROTATION_PROPERTY
from ..errors import AdjustError
from ..reading.pose import CHANNEL_SIZES, as_batch

# An unconnected bone's location is rewritten only when its head moved by more than this (armature units,
# relative to the rig's size): mathutils works in float32, so an unmoved head comes back ~1e-7 off.
_HEAD_MOVED_TOLERANCE = 1e-5


def armature_rotations_to_channels(obj, snapshot, new_pose, bones):
    """Local channels that put ``bones`` (k names or indices) at the armature-space matrices ``new_pose``
    ((k,4,4), or (F,k,4,4) for a batched snapshot): translation = the bone's new head; of the linear part only
    the orientation counts (each bone keeps its scale).

    Works top-down from the snapshot alone (no scene update in between): parents' solved matrices feed
    their children's conversion; bones between moved ones that are not listed keep their local channels
    and are carried along. Returns {bone name: {property: value}} with value an (n,) array (n = the
    property's size), (F,n) when batched:
      - the rotation property of the bone's rotation mode, continuous with the snapshot's current value
        (and, when batched, frame to frame): quaternion in the same hemisphere, Euler via compatible
        angles, axis-angle with the nearest axis sign and angle turn;
      - 'location' only for an unconnected bone whose head moved relative to its parent (the root bone when
        the pelvis moves). Connected bones ignore location; scale is never written.
    """
    idx = _listed_once(snapshot, bones)
    return _channels(obj, snapshot, _array(new_pose, snapshot.pose_matrices.shape[:-3] + (len(idx), 4, 4),
                                           "new_pose"), idx)


def _listed_once(snapshot, bones):
    idx = snapshot.indices(bones)
    if len(set(idx.tolist())) != len(idx):
        raise ValueError("armature_rotations_to_channels: a bone is listed twice")
    return idx


def _channels(obj, snapshot, armature, idx):
    if not snapshot.batched:
        return {name: {prop: values[0] for prop, values in props.items()}
                for name, props in _channels_per_frame(obj, as_batch(snapshot), armature[None], idx).items()}
    return _channels_per_frame(obj, snapshot, armature, idx)


def apply_channels(obj, channels):
    """Write single-frame ``channels`` ({bone name: {property: (k,) values}}, as returned by
    armature_rotations_to_channels) into obj's pose bones. Rotations are kept continuous with each bone's
    current value (quaternion hemisphere, compatible Euler, nearest axis-angle); a rotation property that
    does not match the bone's rotation mode is an error. Plain floats per value: numpy's per-call cost on a few
    values per bone was most of a Live update's writing."""
    pose_bones = obj.pose.bones
    writes = []
    for name, props in channels.items():  # check everything before writing anything
        pose_bone = pose_bones.get(name)
        if pose_bone is None:
            raise AdjustError(f"The armature has no bone named '{name}'")
        mode = pose_bone.rotation_mode
        for prop, value in props.items():
            value = np.asarray(value, dtype=np.float64)
            if prop not in CHANNEL_SIZES or value.shape != (CHANNEL_SIZES[prop],):
                raise ValueError(f"apply_channels: bone '{name}': {prop} needs {CHANNEL_SIZES.get(prop, '?')} "
                                 f"values, got shape {value.shape}")
            value = value.tolist()
            if not all(math.isfinite(v) for v in value):
                raise ValueError(f"apply_channels: bone '{name}': {prop} has NaN/inf")
            if prop.startswith("rotation_") and ROTATION_PROPERTY[mode] != prop:
                raise ValueError(f"apply_channels: bone '{name}' rotates in mode {mode}, not by {prop}")
            writes.append((pose_bone, mode, prop, value))
    for pose_bone, mode, prop, value in writes:
        if prop.startswith("rotation_"):
            value = continuous_rotation(prop, mode, value, getattr(pose_bone, prop))
        setattr(pose_bone, prop, value)


def continuous_rotation(prop, mode, value, reference):
    """``value`` (a rotation stored in ``prop`` for rotation ``mode``; a list, an array or a mathutils value)
    re-expressed as the representation of the same rotation nearest ``reference``: a list for a list, else an
    array. Already-continuous values come back unchanged (bit for bit). Compared in plain floats: numpy's
    per-call cost on a few values per bone was most of a Live update's writing."""
    values, near = [float(v) for v in value], [float(r) for r in reference]
    if prop == "rotation_quaternion":
        dot = values[0] * near[0] + values[1] * near[1] + values[2] * near[2] + values[3] * near[3]
        out = [-v for v in values] if dot < 0.0 else values
    elif prop == "rotation_axis_angle":
        out = _nearest_axis_angle(values[0], values[1:], near).tolist()
    elif all(abs(v - r) <= math.pi for v, r in zip(values, near)):
        out = values
    else:
        out = list(Euler(values, mode).to_matrix().to_euler(mode, Euler(near, mode)))
    return out if isinstance(value, list) else np.array(out)


def _channels_per_frame(obj, snapshot, armature, idx):
    """The batched core of armature_rotations_to_channels: snapshot batched (F,...), ``armature`` the requested
    matrices in armature space (F,k,4,4)."""
    frames = armature.shape[0]
    parents = snapshot.parents
    listed = {int(i): j for j, i in enumerate(idx)}
    # Bones whose pose matrix may change: the listed ones and their unlisted ancestors (such a bone keeps
    # its local channels but is carried along when a listed bone above it moved, e.g. a hip bone between
    # the pelvis and the thigh). Parents come first in index order, so one ascending pass is top-down.
    carried = set()
    for i in listed:
        p = parents[i]
        while p >= 0 and p not in listed and p not in carried:
            carried.add(int(p))
            p = parents[p]
    order = sorted(set(listed) | carried)

    bones = obj.data.bones
    data_bones = {i: bones[snapshot.names[i]] for i in order}
    rest = snapshot.derived("rest Matrix", dict)  # kept: Live converts the same bones again and again
    for i in order + [int(parents[i]) for i in order if parents[i] >= 0]:
        if i not in rest:
            rest[i] = Matrix(snapshot.rest_matrices[i].tolist())  # tolist: Matrix(ndarray) is ~10x slower
    size = snapshot.derived("rig size", lambda: max(1.0, float(np.abs(snapshot.rest_matrices[:, :3, 3]).max())))
    head_tolerance = _HEAD_MOVED_TOLERANCE * size

    target = _reachable_armature_matrices(snapshot, armature, idx)  # (F,k,4,4)
    result = {snapshot.names[i]: {} for i in listed}
    rotation_values = {i: np.empty((frames, CHANNEL_SIZES[ROTATION_PROPERTY[snapshot.rotation_modes[i]]]))
                       for i in listed}
    location_values = {i: np.empty((frames, 3)) for i in listed if not snapshot.use_connect[i]}
    location_moved = {i: False for i in location_values}

    for f in range(frames):
        solved = {}  # bone index -> new armature-space Matrix, for bones that changed
        for i in order:
            p = int(parents[i])
            parent_kwargs = {}
            if p >= 0:
                parent_matrix = solved.get(p)
                if parent_matrix is None:
                    parent_matrix = Matrix(snapshot.pose_matrices[f, p].tolist())
                parent_kwargs = {"parent_matrix": parent_matrix, "parent_matrix_local": rest[p]}
            bone = data_bones[i]
            if i not in listed:
                if p in solved:
                    basis = Matrix(snapshot.channels["matrix_basis"][f, i].tolist())
                    solved[i] = bone.convert_local_to_pose(basis, rest[i], **parent_kwargs)
                continue
            pose_matrix = Matrix(target[f, listed[i]].tolist())
            solved[i] = pose_matrix
            local = bone.convert_local_to_pose(pose_matrix, rest[i], **parent_kwargs, invert=True)
            location, rotation, _scale = local.decompose()
            mode = snapshot.rotation_modes[i]
            prop = ROTATION_PROPERTY[mode]
            reference = rotation_values[i][f - 1] if f else snapshot.channels[prop][0, i]
            rotation_values[i][f] = _rotation_value(rotation, local, mode, reference)
            if i in location_values:
                current = snapshot.channels["location"][f, i]
                location_values[i][f] = current
                if _head_moved(bone, local, location, current, rest[i], pose_matrix, parent_kwargs,
                               head_tolerance):
                    location_values[i][f] = location
                    location_moved[i] = True

    for i in listed:
        props = result[snapshot.names[i]]
        if location_moved.get(i):
            props["location"] = location_values[i]
        props[ROTATION_PROPERTY[snapshot.rotation_modes[i]]] = rotation_values[i]
    return result


def _reachable_armature_matrices(snapshot, armature, idx):
    """The armature-space matrices (F,k,4,4) reduced to what a rigid bone can do: its Y axis (the bone's
    direction) exactly, X/Z re-orthogonalised around it (Z's roll kept), each axis with the length of the
    bone's current pose matrix axis (its scale unchanged). A no-op (to rounding) for reachable input."""
    if armature.shape[0] == 1:
        return _reachable_one_frame(snapshot, armature[0], idx)
    armature = armature.copy()
    linear = armature[..., :3, :3]
    y = linear[..., :, 1]
    z = linear[..., :, 2]
    y = y / _norm(y, "a bone's Y axis")[..., None]
    z = z - dot(z, y)[..., None] * y
    z = z / _norm(z, "a bone's Z axis (parallel to its Y axis)")[..., None]
    x = cross(y, z)  # np.cross costs ~0.1 ms on a few bones
    scale = norm(np.swapaxes(snapshot.pose_matrices[:, idx, :3, :3], -1, -2))  # (F,k,3) column lengths
    armature[..., :3, :3] = np.stack([x, y, z], axis=-1) * scale[..., None, :]
    armature[..., 3, :] = (0.0, 0.0, 0.0, 1.0)
    return armature


def _head_moved(bone, local, location, current, rest, pose_matrix, parent_kwargs, tolerance):
    """Whether keeping the bone's current location would leave its head off the requested one, compared in
    armature space (location is in the parent's possibly scaled space)."""
    if tuple(location) == tuple(current.tolist()):  # np.array_equal costs several times more
        return False
    kept = local.copy()
    kept.translation = Vector(current)
    head = bone.convert_local_to_pose(kept, rest, **parent_kwargs).translation
    return (head - pose_matrix.translation).length > tolerance


def _reachable_one_frame(snapshot, armature, idx):
    """_reachable_armature_matrices of one frame (``armature`` (k,4,4)) in plain floats, with the same operations
    (solver/maths/vectors.py): numpy's per-call cost on a few bones was most of it."""
    out = []
    for matrix, pose_matrix in zip(armature.tolist(), snapshot.pose_matrices[0, idx].tolist()):
        y = _unit((matrix[0][1], matrix[1][1], matrix[2][1]), "a bone's Y axis")
        z = (matrix[0][2], matrix[1][2], matrix[2][2])
        z = _unit(gp.sub(z, gp.scaled(y, gp.dot(z, y))), "a bone's Z axis (parallel to its Y axis)")
        x = gp.cross(y, z)
        scale = [gp.norm((pose_matrix[0][j], pose_matrix[1][j], pose_matrix[2][j])) for j in range(3)]
        out.append([[x[r] * scale[0], y[r] * scale[1], z[r] * scale[2], matrix[r][3]] for r in range(3)]
                   + [[0.0, 0.0, 0.0, 1.0]])
    return np.array([out], dtype=np.float64).reshape(1, len(out), 4, 4)


def _unit(v, what):
    n = gp.norm(v)
    if n < 1e-12:
        raise ValueError(f"new_world: {what} has zero length")
    return gp.divided(v, n)


def _rotation_value(quaternion, local, mode, reference):
    """The rotation of ``local`` (quaternion = its decomposed rotation) in ``mode``, nearest ``reference``."""
    if mode == "QUATERNION":
        value = np.array(quaternion.normalized())
        return -value if np.dot(value, reference) < 0.0 else value
    if mode == "AXIS_ANGLE":
        # In float64 from the quaternion: mathutils' float32 acos loses small angles (~1e-3 rad near 0).
        q = np.array(quaternion.normalized())
        half_sin = np.linalg.norm(q[1:])
        angle = 2.0 * math.atan2(half_sin, q[0])
        axis = q[1:] / half_sin if half_sin > 0.0 else np.zeros(3)
        return _nearest_axis_angle(angle, axis, reference)
    return np.array(local.to_3x3().normalized().to_euler(mode, Euler(reference, mode)))


def _nearest_axis_angle(angle, axis, reference):
    """(angle, x, y, z) of the rotation (angle about axis) whose axis sign and whole turns are nearest the
    reference (angle, x, y, z): (a, n) == (-a, -n) == (a + 2πk, n)."""
    reference = np.asarray(reference, dtype=np.float64)
    axis = np.asarray(axis, dtype=np.float64)
    if not np.any(axis):  # no rotation: any axis will do, keep the reference's
        axis, angle = reference[1:], 0.0
    elif np.dot(axis, reference[1:]) < 0.0:
        axis, angle = -axis, -angle
    turns = round((reference[0] - angle) / (2.0 * math.pi))
    return np.concatenate(([angle + 2.0 * math.pi * turns], axis))

def _array(value, shape, name):
    value = np.asarray(value, dtype=np.float64)
    if value.shape != shape:
        raise ValueError(f"{name} must have shape {shape}, got {value.shape}")
    if not np.all(np.isfinite(value)):
        raise ValueError(f"{name} has NaN/inf")
    return value


def _norm(v, what):
    n = norm(v)
    if (n < 1e-12).any():
        raise ValueError(f"new_world: {what} has zero length")
    return n
