# SPDX-License-Identifier: GPL-3.0-or-later
"""A pose mirrored across the character's own sagittal plane, left and right swapped (numpy only).

The plane is the skeleton's, never the object's axes: vertical (world up, solver/body/facing.UP), across the line
from each right joint to its left partner (the mapped limbs' joints at rest, their parts across up summed, as
facing.lateral takes the hip line), through the midpoints of those pairs. Partners: the bone map's sides, bone by
bone down each limb (arm.L's k-th bone with arm.R's k-th); bones outside the map by their rest geometry (a bone
whose reflected rest head and joint end lie on another's, both ways, is its partner; the trunk's, and any bone
without such a match, is its own).

Each bone's armature-space joint frame is reflected, taken from its partner and turned onto its own rest:
M'_j = S M_p rest_p^-1 S rest_j (p = partner of j, S the reflection): the partner's motion relative to its rest
(M_p rest_p^-1, what it does to the mesh it deforms), reflected, applied to this bone's rest. It honours each
bone's rest whatever its roll (a rig whose left and right rolls are not mirror images still comes out right), is
a proper rotation (S appears twice), and mirroring twice gives the pose back exactly (S S = 1, p(p(j)) = j).
In each bone's own frame that is B'_j = K_j B_p K_j^-1 with K_j = rest_j^-1 S rest_p (``conjugators``): how the
Mirror Pose operator mirrors the pose bones' channels (``mirror_basis``), and how both stay exact twice over on
Blender's float32 rests.
"""

import numpy as np

from ..errors import SolverInputError
from ..body.facing import UP, across
from ..body.joint_ends import end_points
from .rig import leg_length

_SIDES = (("arm.L", "arm.R"), ("hand.L", "hand.R"), ("leg.L", "leg.R"), ("foot.L", "foot.R"))
_MATCH = 0.05  # an unmapped bone's partner: reflected head and joint end within this fraction of the legs' length


def reflection(rig):
    """(4,4) armature-space matrix of the reflection across the rig's sagittal plane at rest (module
    docstring). SolverInputError when the mapped left and right joints do not lie apart."""
    world = rig.matrix_world
    return np.linalg.inv(world) @ _world_reflection(rig) @ world


def mirror_boxes(rig, boxes):
    """World boxes (mins, maxs) (K,3) reflected across the rig's sagittal plane, as the source's motion is: a contact
    object mirrored with the clip that touches it. Each is the axis-aligned box around its reflected corners (the
    box itself where the plane is normal to a world axis)."""
    mins, maxs = (np.asarray(b, dtype=np.float64) for b in boxes)
    pick = np.array([[(c >> axis) & 1 for axis in range(3)] for c in range(8)], dtype=bool)  # (8,3) corner bits
    corners = np.where(pick[None], maxs[:, None], mins[:, None])  # (K,8,3)
    s = _world_reflection(rig)
    reflected = corners @ s[:3, :3].T + s[:3, 3]
    return reflected.min(axis=1), reflected.max(axis=1)


def _world_reflection(rig):
    """(4,4) world matrix of the reflection across the rig's sagittal plane at rest."""
    heads = rig.to_world(rig.rest[:, :3, 3])
    left, right = _mapped_pairs(rig)
    lateral = across(UP, heads[left] - heads[right]).sum(axis=0)
    size = float(np.linalg.norm(lateral))
    if size <= 1e-9 * max(float(np.abs(heads).max()), 1e-300):
        raise SolverInputError("cannot mirror: the left and right limbs do not lie apart across up")
    normal = lateral / size
    point = 0.5 * (heads[left] + heads[right]).mean(axis=0)
    plane = np.eye(4)
    plane[:3, :3] -= 2.0 * np.outer(normal, normal)
    plane[:3, 3] = 2.0 * float(point @ normal) * normal
    return plane


def partners(rig, s=None):
    """(J,) each bone's partner on the other side (itself on the trunk and where none matches): the bone map's
    sides bone by bone, the others by rest geometry (module docstring). SolverInputError when a limb's two sides
    are mapped to different numbers of bones."""
    s = reflection(rig) if s is None else s
    out = np.arange(len(rig.names))
    left, right = _mapped_pairs(rig)
    out[left], out[right] = right, left
    mapped = np.zeros(len(out), dtype=bool)
    for bones in rig.groups.values():
        mapped[list(bones)] = True
    free = np.nonzero(~mapped)[0]
    if len(free):
        heads, ends = rig.rest[:, :3, 3], end_points(rig.rest, rig.ends)
        ref_heads = heads[free] @ s[:3, :3].T + s[:3, 3]
        ref_ends = ends[free] @ s[:3, :3].T + s[:3, 3]
        cost = (np.linalg.norm(ref_heads[:, None] - heads[free][None], axis=-1)
                + np.linalg.norm(ref_ends[:, None] - ends[free][None], axis=-1))
        nearest = np.argmin(cost, axis=1)
        legs = leg_length(rig) / rig.scale  # in armature units, as the rest
        for k, j in enumerate(nearest):
            if nearest[j] == k and cost[k, j] <= _MATCH * legs:
                out[free[k]] = free[j]
    return out


def _mapped_pairs(rig):
    """(left bones, right bones) of the map's sides, bone by bone."""
    left, right = [], []
    for g_left, g_right in _SIDES:
        a, b = rig.groups.get(g_left, ()), rig.groups.get(g_right, ())
        if len(a) != len(b):
            raise SolverInputError(f"cannot mirror: {g_left} is mapped to {len(a)} bones, {g_right} to {len(b)}")
        left += list(a)
        right += list(b)
    return np.array(left, dtype=np.int64), np.array(right, dtype=np.int64)


def conjugators(rig):
    """(J,4,4) K_j = rest_j^-1 S rest_p (p = partner of j): the reflection seen from the partner's rest frame in
    this bone's. Its 3x3 part is made exactly orthogonal (Blender's float32 rests are orthonormal only to about
    1e-5, and a basis with skew cannot be stored as channels) and, pair by pair, K_p = K_j^-1 exactly, so that
    mirroring twice gives back what was mirrored. Returns (K, partners, S)."""
    s = reflection(rig)
    partner = partners(rig, s)
    k = np.linalg.inv(rig.rest) @ s @ rig.rest[partner]
    u, _sigma, vt = np.linalg.svd(k[:, :3, :3])
    k[:, :3, :3] = u @ vt  # the nearest orthogonal matrix (determinant -1: a reflection)
    for j, p in enumerate(partner):
        if p < j:
            k[j] = np.linalg.inv(k[p])
        elif p == j:  # its own partner: an involution, K K = 1, its shift along the reflected direction only
            q = k[j, :3, :3]
            q[:] = 0.5 * (q + q.T)
            normal = np.linalg.eigh(q)[1][:, 0]  # the eigenvector of eigenvalue -1
            k[j, :3, 3] = normal * float(normal @ k[j, :3, 3])
    return k, partner, s


def mirror_pose(rig, pose):
    """Armature-space pose matrices (F,J,4,4) mirrored (module docstring): M'_j = S M_p rest_p^-1 S rest_j
    = S M_p K_j^-1, every bone taking its partner's reflected motion on its own rest."""
    pose = np.asarray(pose, dtype=np.float64)
    k, partner, s = conjugators(rig)
    return s @ pose[:, partner] @ np.linalg.inv(k)


def mirror_basis(rig, basis):
    """Pose bones' matrix_basis (F,J,4,4) mirrored: B'_j = K_j B_p K_j^-1, the local form of mirror_pose where a
    bone's parent's partner is its partner's parent (as left and right limbs hang from the trunk)."""
    basis = np.asarray(basis, dtype=np.float64)
    k, partner, _s = conjugators(rig)
    return k @ basis[:, partner] @ np.linalg.inv(k)
