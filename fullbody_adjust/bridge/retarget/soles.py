"""The soles of an armature's feet as its character's mesh has them (see solver/retarget/soles.py): the lowest
vertices of each foot, skinned to the foot bone and the bones below it, read from every mesh the armature
deforms (an Armature modifier on it, or an armature parent). Nothing here changes Blender data."""

import numpy as np

from ...solver.retarget.soles import FEET
from ..reading.skinning import deformed_meshes

# A vertex belongs to a foot when at least this share of its weight is on the foot bone and the bones below it.
# (The rest of its weight, often on the shin near the heel, moves it with the knee as skinning does: the plan
# sees the transferred knee, the solve may bend it a little more or less, so such a point may slide a few mm,
# which the report measures. Only the wholly foot-weighted vertices are not enough: on real meshes the
# lowest vertices are often shared with the shin.)
_FOOT_SHARE = 0.5
# The sole: the foot's vertices no higher above its lowest one than this fraction of the ankle's height above it.
_SOLE_BAND = 0.6
# At most this many points per sole besides those lowest for some tilt (spread over the sole: the lowest first,
# then each time the farthest from those kept).
_MAX_POINTS = 512


def _vertex_weights(mesh_obj, bone_index):
    """(vertex indices (V,), bones (V,K) int (-1 padding), weights (V,K)) of the vertices weighted to deform
    bones of ``bone_index`` ({vertex group name: bone index})."""
    groups = {g.index: bone_index[g.name] for g in mesh_obj.vertex_groups if g.name in bone_index}
    rows = []
    for v in mesh_obj.data.vertices:
        pairs = [(groups[g.group], g.weight) for g in v.groups if g.group in groups and g.weight > 0.0]
        if pairs:
            rows.append((v.index, pairs))
    width = max((len(p) for _, p in rows), default=1)
    bones = np.full((len(rows), width), -1, dtype=np.int64)
    weights = np.zeros((len(rows), width))
    for r, (_, pairs) in enumerate(rows):
        bones[r, :len(pairs)] = [b for b, _ in pairs]
        weights[r, :len(pairs)] = [w for _, w in pairs]
    return np.array([i for i, _ in rows], dtype=np.int64), bones, weights


def _extremes(points):
    """Indices of the points (N,3) that are lowest for some tilt of the foot: the lowest along each of a fan
    of directions within 90 degrees of straight down (the convex hull's underside, where a foot turned any
    way a foot turns touches the floor first)."""
    tilt = np.radians(np.arange(0.0, 91.0, 7.5))[:, None]
    turn = np.radians(np.arange(0.0, 360.0, 15.0))[None, :]
    down = np.stack([np.sin(tilt) * np.cos(turn), np.sin(tilt) * np.sin(turn),
                     -np.cos(tilt) * np.ones_like(turn)], axis=-1).reshape(-1, 3)
    return np.unique((points @ down.T).argmax(axis=0))


def _spread(points, count):
    """Indices of at most ``count`` of ``points`` (N,3): the lowest, then each time the farthest from those kept."""
    if len(points) <= count:
        return np.arange(len(points))
    kept = [int(points[:, 2].argmin())]
    distance = np.linalg.norm(points - points[kept[0]], axis=1)
    while len(kept) < count:
        k = int(distance.argmax())
        kept.append(k)
        distance = np.minimum(distance, np.linalg.norm(points - points[k], axis=1))
    return np.array(sorted(kept))


def mesh_soles(obj, names, parents, groups, rest):
    """{foot: (points (P,3) armature-space rest, bones (P,K), weights (P,K))} of the feet the meshes ``obj``
    deforms have vertices for (a foot without any is left out: its sole is its joints). ``names``: the rig's
    bone names, ``parents`` (J,), ``groups`` the bone map's {group: bone indices}, ``rest`` (J,4,4)."""
    deform = {b.name for b in obj.data.bones if b.use_deform}
    bone_index = {n: i for i, n in enumerate(names) if n in deform}
    world = np.array(obj.matrix_world, dtype=np.float64)
    to_armature = np.linalg.inv(world)
    points, bones, weights = [], [], []
    for mesh_obj in deformed_meshes(obj):
        index, b, w = _vertex_weights(mesh_obj, bone_index)
        if not len(index):
            continue
        co = np.empty(3 * len(mesh_obj.data.vertices), dtype=np.float32)
        mesh_obj.data.vertices.foreach_get("co", co)
        m = to_armature @ np.array(mesh_obj.matrix_world, dtype=np.float64)
        points.append(co.reshape(-1, 3)[index].astype(np.float64) @ m[:3, :3].T + m[:3, 3])
        bones.append(b)
        weights.append(w)
    if not points:
        return {}
    width = max(b.shape[1] for b in bones)
    bones = np.concatenate([np.pad(b, ((0, 0), (0, width - b.shape[1])), constant_values=-1) for b in bones])
    weights = np.concatenate([np.pad(w, ((0, 0), (0, width - w.shape[1]))) for w in weights])
    points = np.concatenate(points)
    heights = points @ world[2, :3] + world[2, 3]  # world z at rest
    out = {}
    for foot in FEET:
        if not groups.get(foot):
            continue
        ankle = int(groups[foot][0])
        below = np.zeros(len(names), dtype=bool)
        for j, p in enumerate(parents):
            below[j] = j == ankle or (p >= 0 and below[p])
        share = np.where(bones >= 0, below[np.maximum(bones, 0)], False)
        on_foot = (weights * share).sum(axis=1) >= _FOOT_SHARE * weights.sum(axis=1)
        if not on_foot.any():
            continue
        lowest = heights[on_foot].min()
        ankle_z = float((world @ rest[ankle][:, 3])[2])
        band = lowest + _SOLE_BAND * max(ankle_z - lowest, 0.0)
        chosen = np.nonzero(on_foot & (heights <= band))[0]
        in_world = points[chosen] @ world[:3, :3].T
        hull = _extremes(in_world)  # the points a tilted foot stands on, then others spread over the sole
        rest_of = np.setdiff1d(np.arange(len(chosen)), hull)
        extra = rest_of[_spread(in_world[rest_of], max(_MAX_POINTS - len(hull), 0))] if len(rest_of) else rest_of
        chosen = chosen[np.concatenate([hull, extra]).astype(np.int64)]
        out[foot] = (points[chosen], bones[chosen], weights[chosen])
    return out
