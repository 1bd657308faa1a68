"""Motion retargeting (paper §6.2.3), the numpy part: a source rig's motion onto a target rig of other
proportions, as a start pose and effector targets for adjust.adjust_frames, and the solved pose back to
bone channels. No bpy: the bridge (bridge/retarget.py) reads the rigs and actions and writes the keys.

Conventions. A ``Rig`` holds a skeleton's rest (``Bone.matrix_local``, armature space), its body-model groups
(bone indices) and its object's world matrix. Poses are armature-space pose matrices (F,J,4,4), composed as
Blender does (``pose = parent pose @ parent_rest^-1 @ rest @ basis``; a connected bone ignores its location).
Rotation channels follow Blender: Euler angles stored per axis, composed in the mode's order ('XYZ' is
Rz @ Ry @ Rx), quaternions (w, x, y, z), axis-angle (angle, x, y, z).

1. Rotation transfer (``transfer_pose``). Each mapped target bone t takes the WORLD rotation change of its
   source bone s relative to rest, applied to the target's rest turned by an alignment A_t:
       W_t(f) = D_s(f) @ A_t @ W_t_rest,   D_s(f) = W_s(f) @ W_s_rest^-1.
   Limb segments (upper arm, forearm, thigh, shin; hands and feet like the segment they end) are aligned by
   the rest body frames, then the minimal swing taking the target's rest segment direction onto the
   source's, so they point exactly
   where the source's point and T-pose against A-pose or differing bone rolls cancel out. Pelvis, spine,
   clavicles, neck and head are aligned by the rest body frames only (facing and up): there the rigs differ
   by anatomy rather than pose (the CMU clavicle runs from the mid back up to the shoulder, Rigify's along
   the shoulder line), so the target keeps its own spine curve and shoulder line and takes the source's
   changes. Pairing (``pair_bones``):
     - root ↔ root;
     - arm and leg chains pair from the effector end (forearm ↔ forearm, upper arm ↔ upper arm, clavicle ↔
       clavicle); a target bone left over (a clavicle the source lacks) rides rigidly on its parent;
     - trunk and neck: bone k of n pairs with bone k of the source when the counts are equal; otherwise by
       proportional position (target bone centre k+½ of n ↔ source position (k+½)·m/n - ½, the rotation
       changes of the two nearest source bones blended);
     - hand ↔ hand, foot ↔ foot, head ↔ head (a tiny helper bone pointing anywhere, as the CMU hands, does
       not matter: hands and feet are aligned like their chain's last segment);
   unmapped target bones keep their local transform. The root translates so that the hip centre (midpoint
   of the hip joints) goes where the source's does, scaled about the ground below the rest hips by the
   leg-length ratio (target/source, hip joint to ankle).
2. Effector targets (``plan_retarget``): wrists and ankles follow the source's, scaled the same way about
   the ground (= relative to the source's hips, scaled, re-anchored on the target's). Contacts are held
   still over each contact interval (no sliding), blended in and out over a few frames:
     - ground contacts: a planted source foot (ankle slower than ``plant_speed`` for ``plant_min_duration``
       and within ``plant_height`` of its lowest height in the range). Not exact: held at the mean of its
       scaled positions; exact: the same x, y, and z such that the target's sole (the lowest joint of its
       foot, toes and heel, in the transferred foot orientation) is on the ground exactly;
     - object contacts (boxes given): a still effector within ``contact_distance`` of a box. Not exact: held
       at the mean scaled position; exact: held at the mean of the source's own world positions.
   Where a target lies out of its limb's reach, the whole body shifts (smoothly) so that it need not
   stretch: see ``RetargetSettings.reach_margin``.
3. Back to channels (``basis_from_pose`` + ``rotation_channel``): inverse kinematics of the pose matrices,
   rotations in each bone's mode, continuous from frame to frame.
Distances in settings are in source leg lengths (so they hold for any unit and size), durations in seconds.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from .adjust import sub_base_point
from .body import BodyModel, HumanLimits, LimbLimits, default_limits
from .errors import SolverInputError
from .geometry import apply_matrix, cross, dot, norm, normalize, swing_rotation
from .limits import HINGE

EFFECTORS = ("hand.L", "hand.R", "foot.L", "foot.R")
_FEET = ("foot.L", "foot.R")
_EFFECTOR_CHAIN = {"hand.L": "arm.L", "hand.R": "arm.R", "foot.L": "leg.L", "foot.R": "leg.R"}
_EYE4 = np.eye(4)

# --------------------------------------------------------------------------------------------------------
# Rotation channels (Blender's conventions), vectorised

EULER_ORDERS = ("XYZ", "XZY", "YXZ", "YZX", "ZXY", "ZYX")


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
        if not np.any(sel):
            continue
        s = m if p == pick[0] and np.all(sel) else m[sel]  # usually one case covers every matrix: no gather
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


ROTATION_PROPERTY = {"QUATERNION": "rotation_quaternion", "AXIS_ANGLE": "rotation_axis_angle",
                     **{order: "rotation_euler" for order in EULER_ORDERS}}


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


# --------------------------------------------------------------------------------------------------------
# Rigs and kinematics


@dataclass(frozen=True, eq=False)
class Rig:
    """A skeleton: J bones (parents before children), rest matrices (J,4,4) in armature space, rest lengths,
    connected flags, body-model groups (group name -> tuple of bone indices, parent first, as the bone
    mapping gives them) and the armature object's world matrix (4,4), whose scale must be uniform."""

    names: tuple
    parents: np.ndarray
    rest: np.ndarray
    lengths: np.ndarray
    connected: np.ndarray
    groups: dict
    matrix_world: np.ndarray = field(default_factory=lambda: np.eye(4))

    def __post_init__(self):
        names = tuple(self.names)
        j = len(names)
        parents = np.asarray(self.parents, dtype=np.int64).reshape(-1)
        rest = np.asarray(self.rest, dtype=np.float64)
        lengths = np.asarray(self.lengths, dtype=np.float64).reshape(-1)
        connected = np.asarray(self.connected, dtype=bool).reshape(-1)
        world = np.asarray(self.matrix_world, dtype=np.float64)
        if j == 0:
            raise SolverInputError("rig has no bones")
        if parents.shape != (j,) or rest.shape != (j, 4, 4) or lengths.shape != (j,) or connected.shape != (j,):
            raise SolverInputError(f"rig of {j} bones: parents {parents.shape}, rest {rest.shape}, "
                                   f"lengths {lengths.shape}, connected {connected.shape} do not fit")
        if np.any(parents >= np.arange(j)) or np.any(parents < -1):
            raise SolverInputError("rig bones must come after their parents")
        if not (np.all(np.isfinite(rest)) and np.all(np.isfinite(world)) and np.all(np.isfinite(lengths))):
            raise SolverInputError("rig has NaN/inf in its rest or world matrix")
        scales = np.linalg.norm(world[:3, :3], axis=0)
        if world.shape != (4, 4) or not np.all(scales > 0.0) or np.ptp(scales) > 1e-4 * scales.max() \
                or np.linalg.det(world[:3, :3]) <= 0.0:
            raise SolverInputError("armature object scale must be uniform and positive (apply its scale)")
        groups = {g: tuple(int(b) for b in bones) for g, bones in dict(self.groups).items()}
        for g in ("root", "trunk", "arm.L", "arm.R", "hand.L", "hand.R", "leg.L", "leg.R", "foot.L", "foot.R"):
            if not groups.get(g):
                raise SolverInputError(f"rig mapping has no {g!r} group")
        for attr, value in (("names", names), ("parents", parents), ("rest", rest), ("lengths", lengths),
                            ("connected", connected), ("groups", groups), ("matrix_world", world)):
            object.__setattr__(self, attr, value)
        relative = rest.copy()
        has_parent = parents >= 0
        relative[has_parent] = np.linalg.inv(rest[parents[has_parent]]) @ rest[has_parent]
        object.__setattr__(self, "relative", relative)  # parent_rest^-1 @ rest (rest itself for roots)
        object.__setattr__(self, "scale", float(scales.mean()))
        object.__setattr__(self, "rotation", world[:3, :3] / scales)

    def __len__(self):
        return len(self.names)

    def descendants(self, bone):
        """The bone and every bone below it."""
        out = [bone]
        for j in range(bone + 1, len(self.names)):
            if self.parents[j] in out:
                out.append(j)
        return out

    def world_points(self, pose):
        """World heads and tails (F,J,3) of armature-space pose matrices (F,J,4,4)."""
        heads = pose[..., :3, 3]
        tails = heads + pose[..., :3, 1] * self.lengths[:, None]
        return self.to_world(heads), self.to_world(tails)

    def to_world(self, points):
        # A contiguous transpose: numpy multiplies by a strided one about twice as slowly (same result).
        return points @ np.ascontiguousarray(self.matrix_world[:3, :3].T) + self.matrix_world[:3, 3]

    def to_armature(self, points):
        inv = np.linalg.inv(self.matrix_world)
        return points @ np.ascontiguousarray(inv[:3, :3].T) + inv[:3, 3]


def forward_kinematics(rig, basis):
    """Armature-space pose matrices (F,J,4,4) from matrix_basis (F,J,4,4): parent pose @ relative rest @
    basis, top-down; a connected bone ignores its basis translation (as Blender does)."""
    basis = np.array(basis, dtype=np.float64)
    basis[:, rig.connected, :3, 3] = 0.0
    pose = np.empty(basis.shape)
    for j, p in enumerate(rig.parents):
        local = rig.relative[j] @ basis[:, j]
        pose[:, j] = local if p < 0 else pose[:, p] @ local
    return pose


def basis_from_pose(rig, pose, bones):
    """matrix_basis (F,k,4,4) that puts ``bones`` (k indices) at ``pose`` (F,J,4,4), each under its parent's
    pose in the same array: the inverse of forward_kinematics."""
    # Worked on component arrays (entry, frame, bone): a = parent pose @ relative rest, then
    # a^-1 @ pose = (L^-1 P_L, L^-1 (P_t - t)) for a = (L t; 0 1), L^-1 its adjugate over its determinant.
    # Several times faster than batched 4x4 products and an inverse on numpy 1.26, with far fewer temporaries.
    bones = np.asarray(bones, dtype=np.int64)
    parents = rig.parents[bones]
    frames, joints = pose.shape[:2]
    comp = np.ascontiguousarray(np.asarray(pose, dtype=np.float64).reshape(frames, joints, 16)[..., :12]
                                .transpose(2, 0, 1))  # (12,F,J): rows 0-2 of every pose matrix
    p = comp[:, :, np.maximum(parents, 0)]  # copies (fancy indexing)
    p[:, :, parents < 0] = _EYE4.reshape(16)[:12, None, None]
    b = comp[:, :, bones]
    rel = rig.relative[bones].reshape(-1, 16).T  # (16,k)
    a = [[p[4 * i] * rel[j] + p[4 * i + 1] * rel[4 + j] + p[4 * i + 2] * rel[8 + j] for j in range(3)]
         for i in range(3)]
    t = [p[4 * i] * rel[3] + p[4 * i + 1] * rel[7] + p[4 * i + 2] * rel[11] + p[4 * i + 3] for i in range(3)]
    col = [[a[0][j], a[1][j], a[2][j]] for j in range(3)]
    adj = [_cross_of(col[1], col[2]), _cross_of(col[2], col[0]), _cross_of(col[0], col[1])]
    det = col[0][0] * adj[0][0] + col[0][1] * adj[0][1] + col[0][2] * adj[0][2]
    inv = [[adj[i][j] / det for j in range(3)] for i in range(3)]
    out = np.zeros((16,) + b.shape[1:])
    for i in range(3):
        shift = -(inv[i][0] * t[0] + inv[i][1] * t[1] + inv[i][2] * t[2])
        for j in range(4):
            row = out[4 * i + j]
            np.multiply(inv[i][0], b[j], out=row)
            row += inv[i][1] * b[4 + j]
            row += inv[i][2] * b[8 + j]
            if j == 3:
                row += shift
    out[15] = 1.0
    return out.transpose(1, 2, 0).reshape(frames, len(bones), 4, 4)  # a strided view, (F,k,4,4)


def _cross_of(u, v):
    """Cross product of two vectors given as lists of three component arrays."""
    return [u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]]


def affine_inverse(m):
    """Inverses of affine matrices (…,4,4) (last row 0 0 0 1), in closed form: numpy's batched inv is
    several times slower for many small matrices. Computed entry by entry on contiguous component arrays
    (adjugate rows = cross products of the columns, over the determinant)."""
    m = np.asarray(m, dtype=np.float64)
    a = [[np.ascontiguousarray(m[..., i, j]) for j in range(3)] for i in range(3)]
    col = [[a[0][j], a[1][j], a[2][j]] for j in range(3)]
    rows = [_cross_of(col[1], col[2]), _cross_of(col[2], col[0]), _cross_of(col[0], col[1])]
    det = col[0][0] * rows[0][0] + col[0][1] * rows[0][1] + col[0][2] * rows[0][2]
    out = np.zeros(m.shape)
    inv = [[rows[i][j] / det for j in range(3)] for i in range(3)]
    t = [np.ascontiguousarray(m[..., i, 3]) for i in range(3)]
    for i in range(3):
        for j in range(3):
            out[..., i, j] = inv[i][j]
        out[..., i, 3] = -(inv[i][0] * t[0] + inv[i][1] * t[1] + inv[i][2] * t[2])
    out[..., 3, 3] = 1.0
    return out


def _unit_columns(m):
    """Rotation parts (…,3,3) with unit columns (a pose matrix's scale removed). The column sums written
    out: numpy's reduction over a short middle axis is several times slower (same rounding)."""
    sq = m * m
    return m / np.sqrt(sq[..., 0:1, :] + sq[..., 1:2, :] + sq[..., 2:3, :])


# --------------------------------------------------------------------------------------------------------
# Measures of a rig


def chain_joints(rig, group, points_heads, points_tails):
    """Joint positions (…,n,3) of a chain group from heads/tails (…,J,3): heads of the bones + the head of the
    group's end bone (hand, foot, head) or, for the trunk, the tail of its last bone."""
    bones = list(rig.groups[group])
    end = {"arm.L": "hand.L", "arm.R": "hand.R", "leg.L": "foot.L", "leg.R": "foot.R"}.get(group)
    if group == "head":
        bones, last = bones[:-1], points_heads[..., rig.groups["head"][-1], :]
        if not bones:
            return points_heads[..., rig.groups["head"], :]
    elif end is not None:
        last = points_heads[..., rig.groups[end][0], :]
    else:
        last = points_tails[..., bones[-1], :]
    return np.concatenate([points_heads[..., bones, :], last[..., None, :]], axis=-2)


def rest_points(rig):
    """World rest heads and tails (J,3)."""
    return rig.world_points(rig.rest)


def leg_lengths(rig):
    """Rest lengths (2,) (world units) of the left and right legs, hip joint to ankle along the chain."""
    heads, tails = rest_points(rig)
    return np.array([float(norm(np.diff(chain_joints(rig, side, heads, tails), axis=0)).sum())
                     for side in ("leg.L", "leg.R")])


def leg_length(rig):
    """Mean rest length (world units) of the two legs."""
    return float(leg_lengths(rig).mean())


def body_frame(rig, heads, tails):
    """(…,3,3) orthonormal body axes as columns (left, up x left, up): up = root head -> SC, left = right hip
    -> left hip (its part perpendicular to up)."""
    root = rig.groups["root"][0]
    sc = tails[..., rig.groups["trunk"][-1], :]
    up = normalize(sc - heads[..., root, :], fallback=np.array([0.0, 0.0, 1.0]))
    left = heads[..., rig.groups["leg.L"][0], :] - heads[..., rig.groups["leg.R"][0], :]
    left = normalize(left - dot(left, up)[..., None] * up, fallback=np.array([1.0, 0.0, 0.0]))
    return np.stack([left, cross(up, left), up], axis=-1)


def ankle_above_sole(rig, heads, tails):
    """Per frame, how far (world z) each ankle is above the lowest joint of its foot (toes, heel): (F,2)
    for L, R, of world heads/tails (F,J,3)."""
    out = []
    for foot in _FEET:
        bone = rig.groups[foot][0]
        below = rig.descendants(bone)
        lowest = np.minimum(heads[:, below, 2].min(axis=1), tails[:, below, 2].min(axis=1))
        out.append(heads[:, bone, 2] - lowest)
    return np.stack(out, axis=1)


def sole_heights(rig, heads, tails):
    """Per frame, the lowest world z of any joint of either foot (heads/tails (F,J,3)): (F,)."""
    below = sorted(set(rig.descendants(rig.groups["foot.L"][0])) | set(rig.descendants(rig.groups["foot.R"][0])))
    return np.minimum(heads[:, below, 2].min(axis=1), tails[:, below, 2].min(axis=1))


# --------------------------------------------------------------------------------------------------------
# Bone pairing and rotation transfer


@dataclass(frozen=True)
class BonePair:
    """Target bone ``target`` takes the blended rotation change of ``sources`` (indices, weights summing to
    1) applied to its rest turned by ``alignment`` (3,3, world: target rest onto source rest) — or, with no
    sources, rides rigidly on ``rides_on`` (its nearest paired ancestor)."""

    target: int
    sources: tuple
    weights: tuple
    alignment: np.ndarray
    rides_on: int = -1


def pair_bones(source, target):
    """BonePairs for every mapped bone of ``target`` (parents first).

    Alignment: limb segments (upper arm, forearm, thigh, shin, and the hand and foot like the segment they
    end) by the rest body frames (facing), then the minimal swing from the target's rest segment direction
    onto the source's, so a T-pose source drives an A-pose target; the rest (pelvis, spine, clavicles, neck,
    head) by the rest body frames only, so the target keeps its own spine curve and shoulder line where rigs
    differ by anatomy (e.g. the CMU clavicle spans from the mid back up to the shoulder, Rigify's lies along
    the shoulder line)."""
    s_heads, s_tails = rest_points(source)
    t_heads, t_tails = rest_points(target)
    s_dirs = _segment_directions(source, s_heads, s_tails)
    t_dirs = _segment_directions(target, t_heads, t_tails)
    body = body_frame(source, s_heads, s_tails) @ body_frame(target, t_heads, t_tails).T
    pairs = {}

    def pair(t, sources, weights=(1.0,), alignment=body):
        pairs[t] = BonePair(t, tuple(sources), tuple(weights), alignment)

    pair(target.groups["root"][0], source.groups["root"])
    for group in ("arm.L", "arm.R", "leg.L", "leg.R"):
        t_bones, s_bones = target.groups[group], source.groups[group]
        limb = 2 if group.startswith("arm") else len(t_bones)  # upper arm and forearm; every leg bone
        for k in range(1, min(len(t_bones), len(s_bones)) + 1):
            t, s = t_bones[-k], s_bones[-k]
            # Facing first, then the minimal swing of the segment (a swing alone would lose a turn about it).
            pair(t, (s,), alignment=swing_rotation(body @ t_dirs[t], s_dirs[s]) @ body if k <= limb else body)
    for group in ("trunk", "head"):
        t_bones = list(target.groups.get(group, ()))
        s_bones = list(source.groups.get(group, ()))
        if group == "head" and t_bones and s_bones:
            pair(t_bones[-1], (s_bones[-1],))  # head bone <-> head bone; the necks in between
            t_bones, s_bones = t_bones[:-1], s_bones[:-1]
        n, m = len(t_bones), len(s_bones)
        for k, t in enumerate(t_bones if m else ()):
            # Bone centre k+1/2 of n <-> the same fraction of the source chain (equal counts: bone k <-> k).
            x = min(max((k + 0.5) * m / n - 0.5, 0.0), m - 1.0)
            lo = int(np.floor(x))
            hi = min(lo + 1, m - 1)
            pair(t, (s_bones[lo], s_bones[hi]) if hi != lo and x > lo else (s_bones[lo],),
                 (1.0 - (x - lo), x - lo) if hi != lo and x > lo else (1.0,))
    for side in ("L", "R"):
        for end, chain in ((f"hand.{side}", f"arm.{side}"), (f"foot.{side}", f"leg.{side}")):
            last = pairs.get(target.groups[chain][-1])
            pair(target.groups[end][0], source.groups[end], alignment=last.alignment if last else body)

    # Mapped bones left without a source ride on their nearest paired ancestor.
    for t in sorted({b for bones in target.groups.values() for b in bones}):
        if t in pairs:
            continue
        p = target.parents[t]
        while p >= 0 and p not in pairs:
            p = target.parents[p]
        if p >= 0:
            pairs[t] = BonePair(t, (), (), body, rides_on=p)
    return [pairs[t] for t in sorted(pairs)]


def _segment_directions(rig, heads, tails):
    """World rest direction (J,3) of each bone's chain segment (head -> next chain joint), else head -> tail."""
    dirs = tails - heads
    for group in ("trunk", "arm.L", "arm.R", "leg.L", "leg.R", "head"):
        if group not in rig.groups:
            continue
        joints = chain_joints(rig, group, heads, tails)
        bones = rig.groups[group][:-1] if group == "head" else rig.groups[group]
        for k, b in enumerate(bones):
            seg = joints[k + 1] - joints[k]
            if norm(seg) > 1e-9 * max(norm(dirs[b]), 1e-300):
                dirs[b] = seg
    return dirs


def _blend_rotations(rotations, weights):
    """Normalised weighted sum of quaternions (nlerp) of (F,k,3,3) rotations -> (F,3,3)."""
    if len(weights) == 1:
        return rotations[:, 0]
    q = quaternions_of(rotations)
    q = np.where((np.sum(q * q[:, :1], axis=-1) < 0.0)[..., None], -q, q)
    blended = np.einsum("fkq,k->fq", q, np.asarray(weights))
    return quaternions_to_matrices(blended)


def hip_centres(rig, heads):
    """Midpoint of the two hip joints (thigh heads), (…,3) of heads (…,J,3)."""
    return 0.5 * (heads[..., rig.groups["leg.L"][0], :] + heads[..., rig.groups["leg.R"][0], :])


def transfer_pose(source, source_pose, target, target_basis, hips):
    """Target pose (F,Jt,4,4, armature space) carrying the source's motion (source_pose (F,Js,4,4), source
    armature space): mapped bones take the aligned world rotation change of their source bones, unmapped
    bones keep ``target_basis`` (Jt,4,4), and the root translates so the hip centre is at ``hips`` (F,3,
    world). (The hips, not the root bone's head: where a rig puts its root bone relative to the legs varies,
    e.g. at the hip joints or a hand's width above them.)"""
    source_pose = np.asarray(source_pose, dtype=np.float64)
    frames = source_pose.shape[0]
    pairs = pair_bones(source, target)
    used = sorted({s for pair in pairs for s in pair.sources})
    s_rest = source.rotation @ _unit_columns(source.rest[used, :3, :3])
    # The world rotation change since rest of each used source bone, seen in the target's armature space.
    # (Contiguous operands: numpy multiplies strided stacks of small matrices several times slower.)
    changes = target.rotation.T @ source.rotation @ _unit_columns(
        np.ascontiguousarray(source_pose[:, used][..., :3, :3])) @ np.ascontiguousarray(np.swapaxes(s_rest, -1, -2))
    change_of = {s: k for k, s in enumerate(used)}
    t_rest = target.rotation @ _unit_columns(target.rest[:, :3, :3])
    armature_rot = {}  # target bone -> (F,3,3) rotation in the target's armature space
    for pair in pairs:
        t = pair.target
        if pair.sources:
            change = _blend_rotations(changes[:, [change_of[s] for s in pair.sources]], pair.weights)
            armature_rot[t] = change @ (pair.alignment @ t_rest[t])
        else:  # rigid on the paired ancestor: keep the rest relation to it
            armature_rot[t] = armature_rot[pair.rides_on] @ (t_rest[pair.rides_on].T @ t_rest[t])

    # Unmapped bones keep their (static) basis; a mapped bone keeps its own scale, not its rotation.
    basis = np.array(target_basis, dtype=np.float64)
    basis[target.connected, :3, 3] = 0.0
    local = target.relative @ basis  # (Jt,4,4)
    own_scale = np.sqrt(np.sum(basis[:, :3, :3] ** 2, axis=-2))  # (Jt,3)
    local_rot, local_head = np.ascontiguousarray(local[:, :3, :3]), np.ascontiguousarray(local[:, :3, 3])
    # Bone-major: each bone's frames contiguous (faster than strided slices), copied into place once.
    rotations = np.empty((len(target), frames, 3, 3))
    heads = np.empty((len(target), frames, 3))
    for j, p in enumerate(target.parents):
        if j in armature_rot:
            np.multiply(armature_rot[j], own_scale[j], out=rotations[j])
        elif p < 0:
            rotations[j] = local_rot[j]
        else:
            np.matmul(rotations[p], local_rot[j], out=rotations[j])
        if p < 0:
            heads[j] = local_head[j]
        else:
            np.add(rotations[p] @ local_head[j], heads[p], out=heads[j])
    pose = np.empty((frames, len(target), 4, 4))
    pose[..., :3, :3] = rotations.transpose(1, 0, 2, 3)
    pose[..., :3, 3] = heads.transpose(1, 0, 2)
    pose[..., 3, :3] = 0.0
    pose[..., 3, 3] = 1.0
    # Put the hip centre where it belongs.
    hips_now = target.to_world(hip_centres(target, pose[..., :3, 3]))
    translate_body(target, pose, np.asarray(hips, dtype=np.float64) - hips_now)
    return pose


def translate_body(rig, pose, world_shift):
    """Move the root and every bone below it by ``world_shift`` (F,3) in place (pose: armature space)."""
    root = rig.groups["root"][0]
    shift = world_shift @ rig.matrix_world[:3, :3] / rig.scale ** 2  # world -> armature vectors (M⁻¹ = Mᵀ/s²)
    below = np.zeros(len(rig), dtype=bool)
    for j, p in enumerate(rig.parents):
        below[j] = j == root or (p >= 0 and below[p])
    heads = pose[..., :3, 3]  # a view: moved in place
    heads[:, below] += shift[:, None, :]


# --------------------------------------------------------------------------------------------------------
# Contacts and effector targets


@dataclass(frozen=True)
class RetargetSettings:
    """fps: frames per second of the timeline (speeds are per second);
    plant_speed: a foot (or a hand on an object) moving slower than this many source leg lengths per second
        may be in contact; plant_height: a planted ankle is within this many leg lengths of its lowest height
        in the range; plant_min_duration: seconds a contact must last;
    contact_distance: an effector within this many leg lengths of a contact box touches it;
    blend_duration: seconds over which a held contact blends in and out of the free trajectory (and the
        window over which the body's shift is smoothed);
    reach_margin: where a hand or foot target lies beyond its limb's reach (upper arm + forearm from the
        shoulder, thigh + shin from the hip) less this fraction, the whole body shifts, smoothly from frame to
        frame, just far enough (feet first): otherwise, frame by frame, a target just inside the reach leaves
        the root and chest where they are and one just beyond moves them, and the body pops;
    settle_margin: after smoothing the shift, each target is within its reach less this fraction;
    exact: contacts go exactly to the ground / the source's world positions (module docstring)."""

    fps: float = 24.0
    plant_speed: float = 0.3
    plant_height: float = 0.08
    plant_min_duration: float = 0.1
    contact_distance: float = 0.15
    blend_duration: float = 0.1
    reach_margin: float = 0.03
    settle_margin: float = 0.015
    exact: bool = False

    def __post_init__(self):
        for name in ("fps", "plant_speed", "plant_height", "contact_distance"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and np.isfinite(v) and v > 0):
                raise SolverInputError(f"{name} must be a positive number")
        for name in ("plant_min_duration", "blend_duration", "reach_margin", "settle_margin"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and np.isfinite(v) and v >= 0):
                raise SolverInputError(f"{name} must be a number >= 0")

    def frames(self, seconds):
        return max(int(round(seconds * self.fps)), 1)


def still_frames(positions, fps, max_speed):
    """(F,) bool: the point (F,3) moves slower than ``max_speed`` per second (central differences)."""
    positions = np.asarray(positions, dtype=np.float64)
    if len(positions) < 2:
        return np.ones(len(positions), dtype=bool)
    speed = norm(np.gradient(positions, axis=0)) * fps
    return speed < max_speed


def intervals(mask, min_length=1, max_gap=0):
    """[(start, stop)] half-open runs of True in ``mask`` (F,): runs separated by at most ``max_gap`` frames
    are joined (a contact flickering for a frame or two is one contact), then runs shorter than
    ``min_length`` dropped."""
    mask = np.asarray(mask, dtype=bool)
    edges = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    runs = [[int(a), int(b)] for a, b in zip(np.nonzero(edges == 1)[0], np.nonzero(edges == -1)[0])]
    joined = []
    for run in runs:
        if joined and run[0] - joined[-1][1] <= max_gap:
            joined[-1][1] = run[1]
        else:
            joined.append(run)
    return [(a, b) for a, b in joined if b - a >= min_length]


def _contact_runs(candidate, settings):
    n = settings.frames(settings.plant_min_duration) if settings.plant_min_duration else 1
    return intervals(candidate, n, max_gap=n)


def detect_plants(ankles, up, fps, leg, settings=RetargetSettings()):
    """Planted intervals of one foot: ankle positions (F,3) (world; ``up`` the index of the vertical axis),
    still (slower than plant_speed·leg per second) and within plant_height·leg of the foot's lowest height,
    for at least plant_min_duration (shorter interruptions are bridged). Returns [(start, stop)]."""
    ankles = np.asarray(ankles, dtype=np.float64)
    height = ankles[:, up]
    low = np.percentile(height, 2) if len(height) else 0.0
    candidate = still_frames(ankles, fps, settings.plant_speed * leg) & (height <= low + settings.plant_height * leg)
    return _contact_runs(candidate, settings)


def box_distance(points, mins, maxs):
    """Distance (…,K) from points (…,3) to each closed box (K,3)/(K,3) (0 inside)."""
    p = np.asarray(points, dtype=np.float64)[..., None, :]
    gap = np.maximum(np.maximum(mins - p, p - maxs), 0.0)
    return norm(gap)


def detect_object_contacts(points, mins, maxs, fps, leg, settings=RetargetSettings()):
    """Intervals [(start, stop)] where the point (F,3) is still and within contact_distance·leg of a box."""
    if len(mins) == 0:
        return []
    near = box_distance(points, mins, maxs).min(axis=-1) <= settings.contact_distance * leg
    still = still_frames(points, fps, settings.plant_speed * leg)
    return _contact_runs(near & still, settings)


def hold(free, holds, blend):
    """Trajectory (F,3): ``free`` (F,3), with each (start, stop, point) of ``holds`` held at ``point`` over
    [start, stop) and blended in/out over ``blend`` frames either side (smoothstep weights); where the blends
    of two holds overlap, their points are averaged by weight, so the result is continuous."""
    free = np.asarray(free, dtype=np.float64)
    if not holds:
        return free.copy()
    f = np.arange(len(free))
    weights = []
    for start, stop, _ in holds:
        outside = np.maximum(np.maximum(start - f, f - (stop - 1)), 0) / (blend + 1.0)
        x = np.clip(1.0 - outside, 0.0, 1.0)
        weights.append(x * x * (3.0 - 2.0 * x))
    weights = np.stack(weights)  # (H,F)
    points = np.stack([np.asarray(p, dtype=np.float64) for _, _, p in holds])
    total = weights.sum(axis=0)
    mix = (weights.T @ points) / np.maximum(total, 1e-300)[:, None]
    amount = np.minimum(total, 1.0)[:, None]
    return free + amount * (mix - free)


def moving_average(values, half_width):
    """Mean over ±half_width frames (the ends repeated) of values (F,…)."""
    values = np.asarray(values, dtype=np.float64)
    if half_width <= 0 or len(values) < 2:
        return values.copy()
    w = int(half_width)
    padded = np.concatenate([np.repeat(values[:1], w, axis=0), values, np.repeat(values[-1:], w, axis=0)])
    total = np.cumsum(np.concatenate([np.zeros((1,) + values.shape[1:]), padded]), axis=0)
    return (total[2 * w + 1:] - total[:-2 * w - 1]) / (2 * w + 1)


def body_shift(bases, targets, reach, priorities, margin, settle_margin, half_width):
    """World shifts (F,3) of the whole body that bring each target (F,E,3) within its limb's ``reach`` (E,)
    less ``margin`` from the limb's base (F,E,3): the smallest shift on each frame (nearest point of the
    intersection of the reach balls, the paper's two-sphere construction; where they do not meet, the
    higher ``priorities`` first), smoothed over ±half_width frames, then the smallest further shift that
    puts every target within its reach less ``settle_margin`` again. Zero where every target is in reach.
    Continuous from frame to frame, as the nearest point of a convex set is."""
    centres = targets - bases  # a shift d serves target k when |centres_k - d| <= radius_k
    frames = len(targets)
    active = np.ones(centres.shape[:2], dtype=bool)
    zero = np.zeros((frames, 3))

    def nearest(start, fraction):
        radii = np.broadcast_to((1.0 - fraction) * np.asarray(reach, dtype=np.float64), active.shape)
        point, _ = sub_base_point(start, centres, radii, active, priorities, "priority")
        return point

    first = nearest(zero, margin)
    return nearest(moving_average(first, half_width), settle_margin)


@dataclass
class RetargetPlan:
    """What the solve needs and what the caller reports, for F frames.

    start_pose (F,Jt,4,4): the transferred pose (target armature space); heads/tails (F,Jt,3) of it in
    armature space; targets (F,4,3) for EFFECTORS in armature space, world_targets the same in world space;
    contacts (F,4) bool: frames held at a contact (planted foot, object contact); leg_ratio target/source;
    ground: world z of the ground (the source's lowest foot joints)."""

    start_pose: np.ndarray
    heads: np.ndarray
    tails: np.ndarray
    targets: np.ndarray
    world_targets: np.ndarray
    contacts: np.ndarray
    contact_intervals: dict
    leg_ratio: float
    ground: float
    effectors: tuple = EFFECTORS


def plan_retarget(source, source_pose, target, target_basis, settings=RetargetSettings(), boxes=None):
    """The start pose and effector targets that carry ``source_pose`` (F,Js,4,4, source armature space)
    over to ``target`` (its unmapped bones at ``target_basis`` (Jt,4,4)). ``boxes``: (mins, maxs) (K,3)
    each, world boxes of a contact object (None: the ground is the contact). See the module docstring."""
    if not isinstance(source, Rig) or not isinstance(target, Rig):
        raise SolverInputError("source and target must be Rigs")
    source_pose = np.asarray(source_pose, dtype=np.float64)
    if source_pose.ndim != 4 or source_pose.shape[1:] != (len(source), 4, 4) or len(source_pose) == 0:
        raise SolverInputError(f"source pose must have shape (F,{len(source)},4,4), got {source_pose.shape}")
    if not np.all(np.isfinite(source_pose)):
        raise SolverInputError("source pose has NaN/inf")
    target_basis = np.asarray(target_basis, dtype=np.float64)
    if target_basis.shape != (len(target), 4, 4):
        raise SolverInputError(f"target basis must have shape ({len(target)},4,4), got {target_basis.shape}")
    leg_s, leg_t = leg_length(source), leg_length(target)
    if not (leg_s > 0.0 and leg_t > 0.0):
        raise SolverInputError("a rig's legs have zero length")
    ratio = leg_t / leg_s

    s_heads, s_tails = source.world_points(source_pose)
    ground = float(np.percentile(sole_heights(source, s_heads, s_tails), 2))
    # Scale about the ground below each rig's rest hips: the source's motion, re-anchored on the target.
    anchor_s = hip_centres(source, rest_points(source)[0])
    anchor_t = hip_centres(target, rest_points(target)[0])
    anchor_s[2] = anchor_t[2] = ground

    def scaled(points):
        return anchor_t + ratio * (points - anchor_s)

    start = transfer_pose(source, source_pose, target, target_basis, scaled(hip_centres(source, s_heads)))

    free = {e: scaled(s_heads[:, source.groups[e][0]]) for e in EFFECTORS}
    exact_source = {e: s_heads[:, source.groups[e][0]] for e in EFFECTORS}
    blend = settings.frames(settings.blend_duration) if settings.blend_duration else 0
    t_heads, t_tails = target.world_points(start)
    soles = ankle_above_sole(target, t_heads, t_tails)  # the transferred feet's own ankle heights
    frames = len(source_pose)
    contacts = np.zeros((frames, len(EFFECTORS)), dtype=bool)
    found = {}
    world_targets = np.empty((frames, len(EFFECTORS), 3))
    for k, e in enumerate(EFFECTORS):
        if boxes is None:
            runs = detect_plants(exact_source[e], 2, settings.fps, leg_s, settings) if e in _FEET else []
        else:
            runs = detect_object_contacts(exact_source[e], boxes[0], boxes[1], settings.fps, leg_s, settings)
        holds = []
        for a, b in runs:
            if boxes is None:
                point = free[e][a:b].mean(axis=0)
                if settings.exact:  # the target's sole on the ground
                    point[2] = ground + soles[a:b, _FEET.index(e)].mean()
            else:
                point = (exact_source[e] if settings.exact else free[e])[a:b].mean(axis=0)
            holds.append((a, b, point))
            contacts[a:b, k] = True
        found[e] = runs
        world_targets[:, k] = hold(free[e], holds, blend)
    # Every target within its limb's reach (see reach_margin): shift the whole body, smoothly, where needed.
    bases, reach = [], []
    rest_heads, rest_tails = rest_points(target)
    for e in EFFECTORS:
        chain = _EFFECTOR_CHAIN[e]
        bases.append(target.to_world(start[:, target.groups[chain][-2], :3, 3]))  # shoulder, hip joint
        last_two = chain_joints(target, chain, rest_heads, rest_tails)[-3:]  # upper arm + forearm, thigh + shin
        reach.append(float(norm(np.diff(last_two, axis=0)).sum()))
    feet_first = [2.0 if e.startswith("hand") else 3.0 for e in EFFECTORS]
    shift = body_shift(np.stack(bases, axis=1), world_targets, reach, feet_first, settings.reach_margin,
                       settings.settle_margin, blend)
    translate_body(target, start, shift)
    heads = start[..., :3, 3]
    tails = heads + start[..., :3, 1] * target.lengths[:, None]
    return RetargetPlan(start_pose=start, heads=heads, tails=tails, targets=target.to_armature(world_targets),
                        world_targets=world_targets, contacts=contacts, contact_intervals=found, leg_ratio=ratio,
                        ground=ground)


def body_model(rig):
    """(BodyModel, bones): the body model of the rig's mapped bones and their ancestors (``bones``, indices
    into the rig, parents first). The solve needs nothing else: the other bones (fingers, toes, face) ride
    on these and are not written."""
    keep = set()
    for bones in rig.groups.values():
        for b in bones:
            while b >= 0 and b not in keep:
                keep.add(b)
                b = rig.parents[b]
    bones = sorted(keep)
    index = {b: i for i, b in enumerate(bones)}
    model = BodyModel.from_description([rig.names[b] for b in bones],
                                       [index[rig.parents[b]] if rig.parents[b] >= 0 else -1 for b in bones],
                                       {g: [rig.names[b] for b in members] for g, members in rig.groups.items()})
    return model, np.array(bones, dtype=np.int64)


def solved_pose(plan, rotations, heads, bones):
    """Pose matrices (F,J,4,4) after an adjustment of ``bones`` (k indices): their world rotation deltas
    ``rotations`` (F,k,3,3) applied to the start pose's rotations, their heads (F,k,3) as solved (both in the
    solve's space, the target armature). Other bones keep the start pose (they are not written)."""
    solved = plan.start_pose[:, bones]  # a copy (fancy indexing)
    solved[..., :3, :3] = rotations @ np.ascontiguousarray(solved[..., :3, :3])  # strided stacks multiply slowly
    solved[..., :3, 3] = heads
    pose = plan.start_pose.copy()
    pose[:, bones] = solved
    return pose


# --------------------------------------------------------------------------------------------------------
# Joint limits that turn with the motion

# A limb bent by more than this (radians) shows its hinge plane clearly.
_CLEARLY_BENT = 0.2


def motion_limits(model, start_pose, heads, tails, human=HumanLimits()):
    """Joint limits for adjusting the frames of a motion: body.default_limits of the start poses, except
    each elbow and knee hinge axis, which is fixed in its upper bone's frame (upper arm, thigh) as a real
    elbow or knee is, found from the frames where the limb is clearly bent (their bend axes, weighted by
    how bent). Per-frame axes guessed from each pose alone switch between the bend plane and a fallback as
    a limb straightens, and a knee solved about a switching axis pops sideways. Limbs never clearly bent keep
    the default axes. start_pose (F,J,4,4), heads, tails (F,J,3): the start poses in the solve's space."""
    limits = default_limits(model, heads, tails, human, start_pose[..., :3, 0])
    for name in ("arm.L", "arm.R", "leg.L", "leg.R"):
        limb, current = model.limbs.get(name), limits.get(name)
        if limb is None or current is None or len(limb.bones) < 2:
            continue
        hinge = len(limb.bones) - 1  # the joint between the last two segments
        if current.limits.kind[hinge] != HINGE:
            continue
        joints = limb.joints(heads, tails)
        upper, lower = joints[:, hinge] - joints[:, hinge - 1], joints[:, hinge + 1] - joints[:, hinge]
        bend = cross(upper, lower)
        size = norm(bend)
        weight = np.where(np.arctan2(size, dot(upper, lower)) > _CLEARLY_BENT, 1.0, 0.0)
        frame = _unit_columns(start_pose[:, limb.bones[hinge - 1], :3, :3])  # the upper bone's rotation
        local = np.einsum("fji,fj->i", frame, bend * (weight / np.maximum(size, 1e-300))[:, None])
        if norm(local) < 1e-9:
            continue
        axes = np.broadcast_to(current.limits.hinge_axis, (len(heads),) + current.limits.hinge_axis.shape[-2:]).copy()
        axes[:, hinge] = apply_matrix(frame, local / norm(local))
        limits[name] = LimbLimits(replace(current.limits, hinge_axis=axes), current.parent_direction)
    return limits


# --------------------------------------------------------------------------------------------------------
# Smoothness


def roughness(positions, scale=1.0):
    """Per joint, the largest frame-to-frame change of velocity |p[f+1] - 2 p[f] + p[f-1]| / scale over the
    frames: positions (F,J,3) -> (J,). A pop shows as a spike far above the motion's own roughness."""
    positions = np.asarray(positions, dtype=np.float64)
    if len(positions) < 3:
        return np.zeros(positions.shape[1])
    second = positions[2:] - 2.0 * positions[1:-1] + positions[:-2]
    return norm(second).max(axis=0) / scale


def angular_roughness(rotations):
    """Per bone, the largest change of angular velocity between frames: the angle (radians) between
    consecutive frame-to-frame rotations, rotations (F,J,3,3) -> (J,)."""
    r = np.asarray(rotations, dtype=np.float64)
    if len(r) < 3:
        return np.zeros(r.shape[1])
    step = r[1:] @ np.swapaxes(r[:-1], -1, -2)  # (F-1,J,3,3) rotation from one frame to the next
    change = step[1:] @ np.swapaxes(step[:-1], -1, -2)
    cos = np.clip((np.trace(change, axis1=-2, axis2=-1) - 1.0) * 0.5, -1.0, 1.0)
    return np.arccos(cos).max(axis=0)
