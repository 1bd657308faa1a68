"""Rotation channels as Blender stores them (Euler orders, quaternions, axis-angle), to and from rotation
matrices, vectorised over frames and bones; pose-bone basis matrices."""

from __future__ import annotations

import numpy as np

from ..errors import SolverInputError
from .geometry import all_set, any_set
from ..vocabulary import EULER_ORDERS, ROTATION_PROPERTY


def _axis_rotations(axis, angles):
    c, s = np.cos(angles), np.sin(angles)
    r = np.zeros(np.shape(angles) + (3, 3))
    i, k = [(1, 2), (2, 0), (0, 1)][axis]
    r[..., axis, axis] = 1.0
    r[..., i, i] = c
    r[..., k, k] = c
    r[..., k, i] = s
    r[..., i, k] = -s
    return r


def euler_to_matrices(angles, order):
    """(…,3) angles about X, Y, Z -> (…,3,3); 'XYZ' applies X first: Rz @ Ry @ Rx (as mathutils)."""
    angles = np.asarray(angles, dtype=np.float64)
    i, j, k = ("XYZ".index(a) for a in order)
    return _axis_rotations(k, angles[..., k]) @ _axis_rotations(j, angles[..., j]) @ _axis_rotations(
        i, angles[..., i])


def matrices_to_euler(matrices, order, reference=None):
    """Euler angles (F,…,3) of rotation matrices (F,…,3,3) in ``order``, continuous along the first (frame)
    axis (each angle unwrapped by whole turns) and, with ``reference`` (…,3), starting at the whole turns
    nearest it."""
    m = np.asarray(matrices, dtype=np.float64)
    i, j, k = ("XYZ".index(a) for a in order)
    sign = 1.0 if (j - i) % 3 == 1 else -1.0  # even permutations of XYZ
    out = np.empty(m.shape[:-2] + (3,))
    out[..., i] = np.arctan2(sign * m[..., k, j], m[..., k, k])
    out[..., j] = np.arctan2(-sign * m[..., k, i], np.hypot(m[..., i, i], m[..., j, i]))
    out[..., k] = np.arctan2(sign * m[..., j, i], m[..., i, i])
    if out.ndim >= 2 and len(out) > 1:
        out = np.unwrap(out, axis=0)
    if reference is not None and out.ndim >= 2:
        out = out + 2 * np.pi * np.round((np.asarray(reference, dtype=np.float64) - out[0]) / (2 * np.pi))
    return out


def quaternions_to_matrices(q):
    """(…,4) quaternions (w, x, y, z), normalised first as Blender does -> (…,3,3)."""
    q = np.asarray(q, dtype=np.float64)
    n = np.linalg.norm(q, axis=-1, keepdims=True)
    q = np.where(n > 0.0, q / np.where(n > 0.0, n, 1.0), np.array([1.0, 0.0, 0.0, 0.0]))
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], axis=-1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], axis=-1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], axis=-1),
    ], axis=-2)


def quaternions_of(matrices):
    """Unit quaternions (…,4) (w, x, y, z) of rotation matrices (…,3,3), each with w >= 0 (Shepperd's
    method: built from the largest of 4w², 4x², 4y², 4z², so accurate for any rotation)."""
    m = np.asarray(matrices, dtype=np.float64)
    shape = m.shape[:-2]
    m = m.reshape(-1, 3, 3)
    trace = m[:, 0, 0] + m[:, 1, 1] + m[:, 2, 2]
    pick = np.argmax(np.stack([trace, m[:, 0, 0], m[:, 1, 1], m[:, 2, 2]], axis=-1), axis=-1)
    q = np.empty((len(m), 4))
    for p in range(4):
        sel = pick == p
        if not any_set(sel):
            continue
        s = m if p == pick[0] and all_set(sel) else m[sel]  # usually one case covers every matrix: no gather
        if p == 0:
            r = np.sqrt(1.0 + s[:, 0, 0] + s[:, 1, 1] + s[:, 2, 2]) * 2
            v = [0.25 * r, (s[:, 2, 1] - s[:, 1, 2]) / r, (s[:, 0, 2] - s[:, 2, 0]) / r, (s[:, 1, 0] - s[:, 0, 1]) / r]
        elif p == 1:
            r = np.sqrt(1.0 + s[:, 0, 0] - s[:, 1, 1] - s[:, 2, 2]) * 2
            v = [(s[:, 2, 1] - s[:, 1, 2]) / r, 0.25 * r, (s[:, 0, 1] + s[:, 1, 0]) / r, (s[:, 0, 2] + s[:, 2, 0]) / r]
        elif p == 2:
            r = np.sqrt(1.0 + s[:, 1, 1] - s[:, 0, 0] - s[:, 2, 2]) * 2
            v = [(s[:, 0, 2] - s[:, 2, 0]) / r, (s[:, 0, 1] + s[:, 1, 0]) / r, 0.25 * r, (s[:, 1, 2] + s[:, 2, 1]) / r]
        else:
            r = np.sqrt(1.0 + s[:, 2, 2] - s[:, 0, 0] - s[:, 1, 1]) * 2
            v = [(s[:, 1, 0] - s[:, 0, 1]) / r, (s[:, 0, 2] + s[:, 2, 0]) / r, (s[:, 1, 2] + s[:, 2, 1]) / r, 0.25 * r]
        q[sel] = np.stack(v, axis=-1)
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    q = np.where(q[:, :1] < 0.0, -q, q)
    return q.reshape(shape + (4,))


def matrices_to_quaternions(matrices, reference=None):
    """Unit quaternions (F,…,4) of rotation matrices (F,…,3,3), each in the hemisphere of the one before
    along the first (frame) axis, the first in that of ``reference`` (…,4) if given: interpolating the keys
    then never turns the long way."""
    return _same_hemisphere(quaternions_of(matrices), reference)


def _same_hemisphere(q, reference=None):
    """Flip quaternions (F,…,4) so each is in the hemisphere of the one before (the first: of reference)."""
    flips = np.ones(q.shape[:-1])
    flips[1:] = np.where(np.sum(q[1:] * q[:-1], axis=-1) < 0.0, -1.0, 1.0)
    if reference is not None:
        flips[0] = np.where(np.sum(q[0] * reference, axis=-1) < 0.0, -1.0, 1.0)
    return q * np.cumprod(flips, axis=0)[..., None]


def axis_angle_to_matrices(values):
    """(…,4) (angle, x, y, z) -> (…,3,3); a zero axis is no rotation."""
    values = np.asarray(values, dtype=np.float64)
    axis = values[..., 1:]
    n = np.linalg.norm(axis, axis=-1, keepdims=True)
    half = 0.5 * values[..., :1]
    q = np.concatenate([np.cos(half), np.sin(half) * axis / np.where(n > 0.0, n, 1.0)], axis=-1)
    q = np.where(n > 0.0, q, np.array([1.0, 0.0, 0.0, 0.0]))
    return quaternions_to_matrices(q)


def matrices_to_axis_angle(matrices, reference=None):
    """(F,…,3,3) -> (F,…,4) (angle, x, y, z) from continuous quaternions: the axis keeps its sign from
    frame to frame (the first frame's nearest ``reference`` (…,4)), the angle unwrapped by whole turns."""
    reference_q = None
    if reference is not None:
        ref = np.asarray(reference, dtype=np.float64)
        n = np.linalg.norm(ref[..., 1:], axis=-1, keepdims=True)
        reference_q = np.concatenate([np.cos(0.5 * ref[..., :1]), np.sin(0.5 * ref[..., :1]) * ref[..., 1:]
                                      / np.where(n > 0.0, n, 1.0)], axis=-1)
    q = matrices_to_quaternions(matrices, reference_q)
    half_sin = np.linalg.norm(q[..., 1:], axis=-1)
    angle = 2.0 * np.arctan2(half_sin, q[..., 0])
    axis = np.where(half_sin[..., None] > 1e-12, q[..., 1:] / np.maximum(half_sin, 1e-300)[..., None], np.nan)
    # No rotation at all: any axis will do; keep the frame before's (the reference's, or Y, on the first).
    fallback = np.broadcast_to(np.array([0.0, 1.0, 0.0]) if reference is None else
                               np.asarray(reference, dtype=np.float64)[..., 1:], axis.shape[1:])
    for f in np.unique(np.nonzero(np.isnan(axis[..., 0]))[0]):
        previous = axis[f - 1] if f else fallback
        axis[f] = np.where(np.isnan(axis[f]), previous, axis[f])
    angle = np.unwrap(angle, axis=0)
    if reference is not None:
        angle = angle + 2 * np.pi * np.round((np.asarray(reference, dtype=np.float64)[..., 0] - angle[0])
                                             / (2 * np.pi))
    return np.concatenate([angle[..., None], axis], axis=-1)


def rotation_matrices(mode, values):
    """Rotation matrices (…,3,3) of channel ``values`` stored for rotation ``mode``."""
    if mode == "QUATERNION":
        return quaternions_to_matrices(values)
    if mode == "AXIS_ANGLE":
        return axis_angle_to_matrices(values)
    if mode in EULER_ORDERS:
        return euler_to_matrices(values, mode)
    raise SolverInputError(f"unknown rotation mode {mode!r}")


def rotation_channel(mode, matrices, reference=None):
    """Channel values (F,…,n) for rotation ``mode`` of rotation matrices (F,…,3,3) (frames first, e.g. F
    frames of k bones), continuous frame to frame and starting nearest ``reference`` (…,n) (the bones'
    current values)."""
    if mode == "QUATERNION":
        return matrices_to_quaternions(matrices, reference)
    if mode == "AXIS_ANGLE":
        return matrices_to_axis_angle(matrices, reference)
    if mode in EULER_ORDERS:
        return matrices_to_euler(matrices, mode, reference)
    raise SolverInputError(f"unknown rotation mode {mode!r}")


def basis_matrices(location, rotation, scale):
    """Pose-bone ``matrix_basis`` (…,4,4) = T(location) @ R @ S(scale); rotation (…,3,3)."""
    out = np.zeros(np.shape(rotation)[:-2] + (4, 4))
    out[..., :3, :3] = rotation * np.asarray(scale, dtype=np.float64)[..., None, :]
    out[..., :3, 3] = location
    out[..., 3, 3] = 1.0
    return out
