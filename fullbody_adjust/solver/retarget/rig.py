"""A skeleton for retargeting (``Rig``: rest matrices, groups, world matrix, where each bone ends as a joint and
where each foot's sole is), its forward and inverse kinematics on pose matrices, and measures of it (chain
joints, leg length, body frame, soles).

Joints, not tails: every position measured here is a joint (a bone's head, or its end as solver/body/joint_ends.py
finds it: the head of its chain successor or only child), never the tail an importer left (Blender's glTF
importer may leave one a hundred times past the next joint, its FBX importer points it along the bone's Y)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import SolverInputError
from ..body.facing import UP, skeleton_facing
from .foot_pivots import ball_bone
from ..body.joint_ends import end_points, joint_ends
from .soles import default_soles, descendants, posed_soles, skin_soles
from ..maths.geometry import all_set, any_set, cross, cross_components, dot, norm, normalize
from ..vocabulary import LIMB_EFFECTORS

EFFECTORS = LIMB_EFFECTORS
FEET = ("foot.L", "foot.R")
EFFECTOR_CHAIN = {"hand.L": "arm.L", "hand.R": "arm.R", "foot.L": "leg.L", "foot.R": "leg.R"}
_EYE4 = np.eye(4)
# Rest facings closer than this (radians) are the same: a skeleton's float32 joints, not a turn.
_SAME_FACING = 1e-5

@dataclass(frozen=True, eq=False)
class Rig:
    """A skeleton: J bones (parents before children), rest matrices (J,4,4) in armature space, rest lengths
    (Bone.length: head to TAIL, as the importer left it; only used to find the rest tails), connected flags,
    body-model groups (group name -> tuple of bone indices, parent first, as the bone mapping gives them) and
    the armature object's world matrix (4,4), whose scale must be uniform.

    ends (J,3) or None: each bone's joint end in its own rest frame (joint_ends.joint_ends; None: found here
    from the rest tails and the groups). soles {foot group: (points (P,3) armature-space rest, bones (P,K)
    int, weights (P,K))} or None: the points of each foot's sole, skinned to the bones as a mesh vertex is
    (bridge/retarget/soles reads the lowest vertices of the feet of the character's mesh); None or a foot
    left out: its joints (soles.default_soles: ankle, toes, heel, no tail an importer made up).
    skinned_soles: the feet whose soles are a mesh's (None: those given in ``soles``; a Rig copied with
    dataclasses.replace keeps them). After construction: ``lengths_joint`` (J,) the joint-to-joint rest
    lengths, ``sole_skin`` {foot: (bones,
    local points (P,K,3) in those bones' rest frames, weights)}."""

    names: tuple
    parents: np.ndarray
    rest: np.ndarray
    lengths: np.ndarray
    connected: np.ndarray
    groups: dict
    matrix_world: np.ndarray = field(default_factory=lambda: np.eye(4))
    ends: np.ndarray = None
    soles: dict = None
    skinned_soles: tuple = None

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
        for g in ("root", "trunk", "arm.L", "arm.R", "leg.L", "leg.R", "foot.L", "foot.R"):
            if not groups.get(g):
                raise SolverInputError(f"rig mapping has no {g!r} group")
        groups = {g: bones for g, bones in groups.items() if bones}  # no hand bone: the wrist ends the arm
        if self.ends is None:
            rest_tails = rest[:, :3, 3] + unit_columns(rest[:, :3, :3])[:, :, 1] * lengths[:, None]
            ends = joint_ends(parents, rest, rest_tails, groups)
        else:
            ends = np.asarray(self.ends, dtype=np.float64).reshape(j, 3)
        soles = default_soles(rest, parents, groups, ends, lengths)
        skinned = tuple(f for f in FEET if f in dict(self.soles or {})) if self.skinned_soles is None \
            else tuple(self.skinned_soles)
        object.__setattr__(self, "skinned_soles", skinned)
        soles.update(dict(self.soles or {}))
        for attr, value in (("names", names), ("parents", parents), ("rest", rest), ("lengths", lengths),
                            ("connected", connected), ("groups", groups), ("matrix_world", world),
                            ("ends", ends), ("soles", soles)):
            object.__setattr__(self, attr, value)
        object.__setattr__(self, "lengths_joint", np.linalg.norm(end_points(rest, ends) - rest[:, :3, 3], axis=1))
        object.__setattr__(self, "sole_skin", {foot: skin_soles(rest, *spec) for foot, spec in soles.items()})
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
        return descendants(self.parents, bone)

    def world_points(self, pose):
        """World heads and joint ends (…,J,3) of armature-space pose matrices (…,J,4,4): the ends where
        each bone's joint segment ends (joint_ends), never the importer's tails."""
        pose = np.asarray(pose, dtype=np.float64)
        return self.to_world(pose[..., :3, 3]), self.to_world(end_points(pose, self.ends))

    def sole_points(self, pose, foot):
        """World points (…,P,3) of a foot's sole (``soles``) in armature-space pose matrices (…,J,4,4)."""
        return self.to_world(posed_soles(np.asarray(pose, dtype=np.float64), *self.sole_skin[foot]))

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


def chain_joints(rig, group, heads, ends):
    """Joint positions (…,n,3) of a chain group from heads and joint ends (…,J,3): heads of the bones + the
    head of the group's end bone (hand, foot, head) or, for the trunk and a hand-less arm, its last bone's joint
    end (the SC, the wrist)."""
    bones = list(rig.groups[group])
    end = {"arm.L": "hand.L", "arm.R": "hand.R", "leg.L": "foot.L", "leg.R": "foot.R"}.get(group)
    if group == "head":
        bones, last = bones[:-1], heads[..., rig.groups["head"][-1], :]
        if not bones:
            return heads[..., rig.groups["head"], :]
    elif end in rig.groups:
        last = heads[..., rig.groups[end][0], :]
    else:
        last = ends[..., bones[-1], :]
    return np.concatenate([heads[..., bones, :], last[..., None, :]], axis=-2)


def rest_points(rig):
    """World rest heads and joint ends (J,3)."""
    return rig.world_points(rig.rest)


def leg_lengths(rig):
    """Rest lengths (2,) (world units) of the left and right legs, hip joint to ankle along the chain."""
    heads, ends = rest_points(rig)
    return np.array([float(norm(np.diff(chain_joints(rig, side, heads, ends), axis=0)).sum())
                     for side in ("leg.L", "leg.R")])


def leg_length(rig):
    """Mean rest length (world units) of the two legs."""
    return float(leg_lengths(rig).mean())


def body_frame(rig, heads, ends):
    """(…,3,3) orthonormal body axes as columns (left, up x left, up): up = root head -> SC, left = right hip
    -> left hip (its part perpendicular to up). The body's forward is -(up x left) = left x up."""
    root = rig.groups["root"][0]
    sc = ends[..., rig.groups["trunk"][-1], :]
    up = normalize(sc - heads[..., root, :], fallback=np.array([0.0, 0.0, 1.0]))
    left = heads[..., rig.groups["leg.L"][0], :] - heads[..., rig.groups["leg.R"][0], :]
    left = normalize(left - dot(left, up)[..., None] * up, fallback=np.array([1.0, 0.0, 0.0]))
    return np.stack([left, cross(up, left), up], axis=-1)


def soles_of(rig, pose):
    """{foot: world sole points (…,P,3)} of armature-space pose matrices (…,J,4,4)."""
    return {foot: rig.sole_points(pose, foot) for foot in FEET}


def ankle_above_sole(rig, pose):
    """Per frame, how far (world z) each ankle is above the lowest point of its sole: (F,2) for L, R, of
    armature-space pose matrices (F,J,4,4)."""
    heads = rig.to_world(pose[..., :3, 3])
    return np.stack([heads[:, rig.groups[foot][0], 2] - rig.sole_points(pose, foot)[..., 2].min(axis=-1)
                     for foot in FEET], axis=1)


def sole_heights(rig, pose):
    """Per frame, the lowest world z of either foot's sole, (F,) of pose matrices (F,J,4,4)."""
    return np.minimum(*(rig.sole_points(pose, foot)[..., 2].min(axis=-1) for foot in FEET))


def hip_centres(rig, heads):
    """Midpoint of the two hip joints (thigh heads), (…,3) of heads (…,J,3)."""
    return 0.5 * (heads[..., rig.groups["leg.L"][0], :] + heads[..., rig.groups["leg.R"][0], :])


def effector_points(rig, pose, effector):
    """World points (…,P,3) of a hand or foot of armature-space pose matrices (…,J,4,4): the effector joint
    (wrist, ankle) first; then for a foot its sole's points (Rig.soles) and the ball of the foot (the joint it
    stands on as the heel lifts: foot_pivots.ball_bone; the ankle again on a foot without toes), for a hand the
    hand's joint end and the heads and joint ends of every bone below it (fingers; of a hand-less arm, the bones
    below its forearm)."""
    heads, ends = rig.world_points(pose)
    if effector not in rig.groups:  # no hand bone: the wrist is the forearm's end
        below = rig.descendants(rig.groups[EFFECTOR_CHAIN[effector]][-1])[1:]
        return np.concatenate([effector_joint(rig, heads, ends, effector)[..., None, :], heads[..., below, :],
                               ends[..., below, :]], axis=-2)
    bone = rig.groups[effector][0]
    if effector in FEET:
        ball = ball_bone(rig, effector)
        return np.concatenate([heads[..., [bone], :], rig.sole_points(pose, effector),
                               heads[..., [bone if ball is None else ball], :]], axis=-2)
    below = rig.descendants(bone)[1:]
    return np.concatenate([heads[..., [bone], :], ends[..., [bone], :], heads[..., below, :], ends[..., below, :]],
                          axis=-2)


def effector_joint(rig, heads, ends, effector):
    """The wrist or ankle (…,3) of heads and joint ends (…,J,3): the hand's or foot's head, else (an arm with no
    hand bone) the joint end of the arm's last bone."""
    if effector in rig.groups:
        return heads[..., rig.groups[effector][0], :]
    return ends[..., rig.groups[EFFECTOR_CHAIN[effector]][-1], :]


def rest_forward(rig):
    """The skeleton's facing at rest: its forward (3,) in world space, horizontal and of unit length, from its
    leg joints whatever its object's axes (facing.skeleton_facing, as the bone mapping's sides): the horizontal
    direction from the ankles to the toes (the joint below each foot farthest from its ankle), which is where a
    character looks and walks even when its hips are yawed (GDQuest's mannequin: hip and shoulder lines 13 degrees
    off its face and toes); square across the hip line on the side the map's left says where the toes do not say
    (flat feet pointing sideways, more than 60 degrees off that, or no joint ahead of the ankles)."""
    heads = rig.world_points(rig.rest)[0]
    hips = heads[[rig.groups["leg.L"][0], rig.groups["leg.R"][0]]]
    feet = [rig.groups[foot][0] for foot in FEET]
    below = [heads[rig.descendants(foot)[1:]] for foot in feet]
    tiny = 1e-6 * max(float(np.linalg.norm(hips - heads[feet], axis=1).max()), 1e-300)
    forward = skeleton_facing(UP, hips, heads[feet], below, tiny, left=0).forward
    return forward if forward is not None else np.array([0.0, -1.0, 0.0])


def facing_turn(source, target):
    """(3,3) rotation about world Z by the angle from the source's rest forward to the target's (rest_forward):
    the source's motion turned by it makes the target face its travel as the source faces its own."""
    a, b = rest_forward(source), rest_forward(target)
    angle = np.arctan2(a[0] * b[1] - a[1] * b[0], a[0] * b[0] + a[1] * b[1])
    if abs(angle) < _SAME_FACING:
        return np.eye(3)
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
