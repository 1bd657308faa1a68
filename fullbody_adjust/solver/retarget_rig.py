"""A skeleton for retargeting (``Rig``: rest matrices, groups, world matrix), its forward and inverse
kinematics on pose matrices, and measures of it (chain joints, leg length, body frame, soles)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .errors import SolverInputError
from .geometry import all_set, any_set, cross, cross_components, dot, norm, normalize
from .vocabulary import LIMB_EFFECTORS

EFFECTORS = LIMB_EFFECTORS
FEET = ("foot.L", "foot.R")
EFFECTOR_CHAIN = {"hand.L": "arm.L", "hand.R": "arm.R", "foot.L": "leg.L", "foot.R": "leg.R"}
_EYE4 = np.eye(4)

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
        if any_set(parents >= np.arange(j)) or any_set(parents < -1):
            raise SolverInputError("rig bones must come after their parents")
        if not (all_set(np.isfinite(rest)) and all_set(np.isfinite(world)) and all_set(np.isfinite(lengths))):
            raise SolverInputError("rig has NaN/inf in its rest or world matrix")
        scales = np.linalg.norm(world[:3, :3], axis=0)
        if world.shape != (4, 4) or not all_set(scales > 0.0) or np.ptp(scales) > 1e-4 * scales.max() \
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
    adj = [cross_components(col[1], col[2]), cross_components(col[2], col[0]), cross_components(col[0], col[1])]
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


def unit_columns(m):
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
    for foot in FEET:
        bone = rig.groups[foot][0]
        below = rig.descendants(bone)
        lowest = np.minimum(heads[:, below, 2].min(axis=1), tails[:, below, 2].min(axis=1))
        out.append(heads[:, bone, 2] - lowest)
    return np.stack(out, axis=1)


def sole_heights(rig, heads, tails):
    """Per frame, the lowest world z of any joint of either foot (heads/tails (F,J,3)): (F,)."""
    below = sorted(set(rig.descendants(rig.groups["foot.L"][0])) | set(rig.descendants(rig.groups["foot.R"][0])))
    return np.minimum(heads[:, below, 2].min(axis=1), tails[:, below, 2].min(axis=1))


def hip_centres(rig, heads):
    """Midpoint of the two hip joints (thigh heads), (…,3) of heads (…,J,3)."""
    return 0.5 * (heads[..., rig.groups["leg.L"][0], :] + heads[..., rig.groups["leg.R"][0], :])


def effector_points(rig, heads, tails, effector):
    """World points (…,P,3) of a hand or foot from heads/tails (…,J,3): the effector joint (wrist, ankle)
    first, then the bone's tail and the heads and tails of every bone below it (fingers, toes, heel)."""
    bone = rig.groups[effector][0]
    below = rig.descendants(bone)[1:]
    return np.concatenate([heads[..., [bone], :], tails[..., [bone], :], heads[..., below, :], tails[..., below, :]],
                          axis=-2)


def heading_rotation(matrix):
    """(3,3) rotation about world Z by the heading (yaw) of a rotation (3,3): where it turns the X axis, seen
    from above."""
    if np.hypot(matrix[0, 0], matrix[1, 0]) > 1e-9:
        angle = np.arctan2(matrix[1, 0], matrix[0, 0])
    else:  # X turned upright: the heading of Y, less the quarter turn from X to Y
        angle = np.arctan2(matrix[1, 1], matrix[0, 1]) - 0.5 * np.pi
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
