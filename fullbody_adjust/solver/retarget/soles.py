"""Where a foot's sole is: points carried by the foot's bones as a skinned mesh's vertices are (linear blend
skinning, as Blender's Armature modifier deforms), so the floor and the contacts are measured on the sole the
character's mesh has, not on a joint.

A sole is (points (P,3) in armature space at rest, bones (P,K) int, weights (P,K)): point p follows
sum_k weights[p,k] * pose[bones[p,k]] @ rest[bones[p,k]]^-1 @ points[p] (weights summing to 1; a padding
bone -1 weighs 0). bridge/retarget/soles reads them from the mesh (the lowest vertices of the foot); without a
mesh a foot's sole is its joints (the heads of its bones: ankle, toes, heel; and the leaf tips an importer did
not make up), each riding on its own bone."""

from __future__ import annotations

import numpy as np

FEET = ("foot.L", "foot.R")


def descendants(parents, bone):
    """``bone`` and every bone below it (parents (J,) listed parents first), in that order."""
    out = [bone]
    for j in range(bone + 1, len(parents)):
        if parents[j] in out:
            out.append(j)
    return out


def default_soles(rest, parents, groups, ends, tail_lengths):
    """{foot: (points, bones, weights)} of the feet with no mesh: the rest heads of the foot bone and of every
    bone below it (ankle, ball, toes, heel), and the joint end of each leaf among them whose tail the importer
    left within reach (joint_ends kept it: ``ends`` (J,3) local, as long as ``tail_lengths`` (J,)): a BVH end
    site, a metarig's toe tip or heel. A leaf tail joint_ends had to shorten is the importer's guess: left out."""
    rest = np.asarray(rest, dtype=np.float64)
    heads = rest[:, :3, 3]
    leaf = np.ones(len(parents), dtype=bool)
    leaf[[p for p in parents if p >= 0]] = False
    end_lengths = np.linalg.norm(np.einsum("jik,jk->ji", rest[:, :3, :3], ends), axis=1)
    kept_tail = leaf & (np.abs(end_lengths - tail_lengths) <= 1e-4 * np.maximum(tail_lengths, 1e-12))  # float32 data
    out = {}
    for foot in FEET:
        if not groups.get(foot):
            continue
        bones = np.array(descendants(parents, int(groups[foot][0])), dtype=np.int64)
        tips = bones[kept_tail[bones]]
        points = np.concatenate([heads[bones], np.einsum("jik,jk->ji", rest[tips, :3, :3], ends[tips])
                                 + heads[tips]])
        owners = np.concatenate([bones, tips])
        out[foot] = (points, owners[:, None], np.ones((len(owners), 1)))
    return out


def skin_soles(rest, points, bones, weights):
    """(bones (P,K), local points (P,K,3) in each bone's rest frame, weights (P,K) normalised) of a sole."""
    rest = np.asarray(rest, dtype=np.float64)
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    bones = np.asarray(bones, dtype=np.int64).reshape(len(points), -1)
    weights = np.where(bones >= 0, np.asarray(weights, dtype=np.float64).reshape(bones.shape), 0.0)
    total = weights.sum(axis=1, keepdims=True)
    weights = weights / np.where(total > 0.0, total, 1.0)
    safe = np.maximum(bones, 0)
    inverse = np.linalg.inv(rest[safe])  # (P,K,4,4)
    local = np.einsum("pkij,pkj->pki", inverse[..., :3, :3], points[:, None, :]) + inverse[..., :3, 3]
    return safe, local, weights


def posed_soles(pose, bones, local, weights):
    """Armature-space sole points (…,P,3) of pose matrices (…,J,4,4)."""
    out = 0.0
    for k in range(bones.shape[1]):  # one influence at a time: (…,P,3,4) at most in memory
        m = pose[..., bones[:, k], :3, :]
        out = out + weights[:, k, None] * (np.einsum("...pij,pj->...pi", m[..., :3], local[:, k]) + m[..., 3])
    return out
