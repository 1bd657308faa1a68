"""How thick the limbs are: each bone's radius read from the meshes the armature deforms, so that obstacles keep
a limb's surface out, not only its bones' centre line (solver AdjustSettings.clearance: radius plus Margin).

A bone's radius is measured at rest, in armature units: the vertices weighted mostly to it (more than half
their weight over the armature's deform bones is its vertex group's, or that of a deform bone lying along its
joint segment: a twist bone, a generated rig's DEF- bones along its ORG- bone), their distances from its joint
segment (its head to its chain successor's head, solver.joint_ends), and of those the largest that is not an
outlier (at most the median plus _OUTLIER scaled median absolute deviations: a stray vertex painted to the wrong
bone does not make the limb thick). A limb's radius is the largest of its bones' but an arm's clavicle (from the
neck's base to the shoulder), whose vertices are the torso's: arm.L's radius is its upper arm's or forearm's. A
bone with no vertex has none, and a limb with none keeps the paper's behaviour (no mesh: no radius).

A limb's surface (limb_surfaces, solver AdjustSettings.surface) is those same vertices as points riding rigidly on
the bone each counts for, placed at the start pose: a capsule cannot tell a fist sticking out past the forearm's
joint end, or a flat chunky forearm, from a round limb; the points let the solver keep the mesh itself out where
the target leaves a choice (solver/obstacles/easing.py).

The weights are read vertex by vertex (Blender has no bulk access to them: about 0.15 s for 25 000 vertices), so
they are kept per mesh while its vertices' positions and its vertex groups stay the same (and the radii per
armature while, besides, the meshes' placement and the rig do): weights repainted without any of these changing
are read again only in a new session or file (the meshes' session ids change) or after clear().
"""

from collections import OrderedDict

import numpy as np

from ...solver.body.joint_ends import end_points
from ...solver.obstacles.surface import LimbSurface
from .skinning import deformed_meshes

# A vertex farther from its bone's segment than the median distance plus this many scaled MADs is an outlier.
_OUTLIER = 4.0
# 1.4826 MAD estimates the standard deviation of normally distributed distances; it is taken as at least this
# fraction of the median (a limb modelled as an exact cylinder has a MAD of 0: its wrist ring would be an outlier).
_MAD_SCALE = 1.4826
_LEAST_SPREAD = 0.1
# A deform bone outside the body model belongs to a chain bone when its head and end lie within this fraction of
# that bone's joint segment length from the segment.
_ALONG = 0.05
# A limb's surface points (limb_surfaces): at most this many, the farthest from their bones' joint segments (the
# outermost, which a box meets first).
_MOST = 1024
# Armatures (and meshes) whose measures are kept at once.
_CAPACITY = 16

_radii = OrderedDict()  # armature name -> (fingerprint, _measures' pair)
_weights = OrderedDict()  # mesh object name -> (fingerprint, (vertex, group, weight) arrays)


def limb_clearances(obj, rig, unit, margin):
    """{limb: clearance} in solve units for AdjustSettings.clearance: each limb's radius (limb_radii) at the solve
    space's scale ``unit`` (F,) (the largest, so the clearance kept is at least the radius) plus ``margin`` (solve
    units); limbs without a radius are left out (the paper's behaviour)."""
    scale = float(np.max(unit))
    return {limb: radius * scale + margin for limb, radius in limb_radii(obj, rig).items()}


def limb_radii(obj, rig):
    """{limb: radius} in armature units of the limbs of ``rig`` (rig_cache.Rig of armature ``obj``) that have one."""
    return _measures(obj, rig)[0]


def limb_surfaces(obj, rig, matrices, to_solve):
    """{limb: solver LimbSurface} for AdjustSettings.surface: each arm's and leg's surface points (the vertices
    weighted mostly to its bones, as limb_radii counts them; the _MOST farthest from their bones' joint segments
    where there are more) at the start pose of each frame, in solve space, rigidly on the bone each counts for
    (``matrices`` (F,J,4,4) the bones' world matrices, ``to_solve`` (F,4,4) solve_space's: world to solve space).
    Arms and legs only: theirs is the swivel round the target that keeps a surface out (an elbow, a knee); the
    trunk's and the head's chains have none a surface should turn them by. Limbs without one are left out."""
    out = {}
    for limb, (segment, owner, on_bone, weights) in _measures(obj, rig)[1].items():
        posed = np.einsum("fjab,jb->fja", matrices[:, owner], on_bone)
        out[limb] = LimbSurface(segment, np.einsum("fab,fjb->fja", to_solve, posed)[..., :3], weights)
    return out


def _measures(obj, rig):
    """(limb radii, {limb: (segment (P,), owner bone (P,), points (P,4) homogeneous in their owner's rest frame)}),
    kept per armature while its meshes, their placement and the rig stay the same."""
    meshes = deformed_meshes(obj)
    reads = [_mesh_weights(mesh) for mesh in meshes]
    to_armature = np.linalg.inv(np.array(obj.matrix_world, dtype=np.float64))
    placements = [to_armature @ np.array(mesh.matrix_world, dtype=np.float64) for mesh in meshes]
    key = (tuple(fingerprint for fingerprint, _arrays in reads), tuple(m.tobytes() for m in placements),
           rig.ends.tobytes(), rig.rest["rest_matrices"].tobytes(), rig.model.names, _deform_flags(obj).tobytes())
    kept = _radii.get(obj.name)
    if kept is not None and kept[0] == key:
        _radii.move_to_end(obj.name)
        return kept[1]
    points, owners, distances, blend = owned_points(obj, rig, meshes, [arrays for _fingerprint, arrays in reads],
                                                    placements)
    radii = np.full(len(rig.model.names), np.nan)
    for bone in np.unique(owners):
        radii[bone] = robust_radius(distances[owners == bone])
    out, surfaces = {}, {}
    for name, limb in rig.model.limbs.items():
        bones = limb.bones[-2:] if name.startswith("arm") else limb.bones  # an arm's clavicle is the torso's
        found = radii[list(bones)]
        if np.isfinite(found).any():
            out[name] = float(np.nanmax(found))
        mine = np.nonzero(np.isin(owners, bones))[0] if name.startswith(("arm", "leg")) else []
        if len(mine):
            mine = mine[np.argsort(-distances[mine], kind="stable")[:_MOST]]
            segment = np.array([limb.bones.index(b) for b in owners[mine]], dtype=np.int64)
            on_bone = np.einsum("jab,jb->ja", np.linalg.inv(rig.rest["rest_matrices"][owners[mine]]),
                                np.c_[points[mine], np.ones(mine.size)])
            surfaces[name] = (segment, owners[mine], on_bone, _limb_weights(rig, limb, mine, blend))
    _remember(_radii, obj.name, (key, (out, surfaces)))
    return out, surfaces


def owned_points(obj, rig, meshes, weights, placements):
    """(points (N,3) at rest in armature units, owners (N,) the model bone each counts for, distances (N,) from
    that bone's joint segment, blend: ((M,2) point and deform bone, (M,) its weight) every weight of those
    points) of the vertices of ``meshes`` weighted mostly to one bone that counts for a chain bone (module
    docstring); ``weights``: _mesh_weights' arrays, ``placements``: mesh space -> armature space ((4,4) each)."""
    model = rig.model
    rest = rig.rest["rest_matrices"]
    heads, ends = rest[:, :3, 3], end_points(rest, rig.ends)
    deform = _deform_flags(obj)
    carrier = _carriers(model, heads, ends, deform)
    index = {name: j for j, name in enumerate(model.names) if deform[j]}  # the groups the armature deforms by
    points, owners, blends, at = [], [], [], 0
    for mesh, (vertex, group, weight), placement in zip(meshes, weights, placements):
        group_bone = np.array([index.get(g.name, -1) for g in mesh.vertex_groups] + [-1])
        bone = group_bone[np.minimum(group, len(group_bone) - 1)]
        counted = (bone >= 0) & (weight > 0.0)
        vertex, bone, weight = vertex[counted], bone[counted], weight[counted]
        order = np.lexsort((weight, vertex))  # by vertex, the largest weight last
        last = np.r_[vertex[order][1:] != vertex[order][:-1], True] if vertex.size else np.zeros(0, dtype=bool)
        total = np.bincount(vertex, weight)[vertex[order][last]]
        mostly = weight[order][last] > 0.5 * total  # more than half its weight: not a tie between two bones
        owner = np.where(mostly, carrier[bone[order][last]], -1)  # the chain bone its own bone counts for
        kept = vertex[order][last][owner >= 0]
        if not kept.size:
            continue
        owners.append(owner[owner >= 0])
        points.append(_rest_positions(mesh)[kept] @ placement[:3, :3].T + placement[:3, 3])
        row = np.full(int(vertex.max()) + 1, -1)
        row[kept] = at + np.arange(kept.size)
        mine = row[vertex] >= 0
        blends.append(np.stack([row[vertex[mine]], bone[mine]]).T)
        blends.append(weight[mine])
        at += kept.size
    if not points:
        return np.zeros((0, 3)), np.zeros(0, dtype=np.int64), np.zeros(0), (np.zeros((0, 2), dtype=np.int64),
                                                                             np.zeros(0))
    points, owners = np.concatenate(points), np.concatenate(owners)
    blend = (np.concatenate(blends[0::2]), np.concatenate(blends[1::2]))
    return points, owners, _point_segment(points, heads[owners], ends[owners]), blend


def _limb_weights(rig, limb, points, blend):
    """(P, S+2) the skinning weights of points ``points`` (indices into owned_points' points) over limb ``limb``'s
    S chain segments (a deform bone counts for the chain bone it lies along, _carriers), its end (the end bone and
    every bone below it: the hand or foot, which rides on the end joint) and the rest (the torso: the base), each
    row adding up to 1 (LimbSurface.weights)."""
    model = rig.model
    rest = rig.rest["rest_matrices"]
    deform = np.ones(len(model.names), dtype=bool)
    carrier = _carriers(model, rest[:, :3, 3], end_points(rest, rig.ends), deform)
    segments = len(limb.bones)
    column = np.full(len(model.names), segments + 1)  # the rest
    if limb.end_bone is not None:
        below = np.zeros(len(model.names), dtype=bool)
        below[limb.end_bone] = True
        parents = np.asarray(model.parents)
        for _ in range(len(model.names)):  # every bone below the end bone, a level per pass
            grown = below | ((parents >= 0) & below[np.maximum(parents, 0)])
            if (grown == below).all():
                break
            below = grown
        column[below] = segments
    for k, bone in enumerate(limb.bones):
        column[carrier == bone] = k
    pairs, weight = blend
    row = np.full(int(pairs[:, 0].max()) + 1 if len(pairs) else 0, -1)
    row[points] = np.arange(len(points))
    take = row[pairs[:, 0]] >= 0 if len(pairs) else np.zeros(0, dtype=bool)
    out = np.zeros((len(points), segments + 2))
    np.add.at(out, (row[pairs[take, 0]], column[pairs[take, 1]]), weight[take])
    return out / out.sum(axis=1, keepdims=True)


def robust_radius(distances):
    """The largest of ``distances`` (n,) that is not an outlier (module docstring)."""
    median = float(np.median(distances))
    spread = max(_MAD_SCALE * float(np.median(np.abs(distances - median))), _LEAST_SPREAD * median)
    return float(distances[distances <= median + _OUTLIER * spread].max())


def clear():
    """Forget every kept measure (e.g. when another file is loaded)."""
    _radii.clear()
    _weights.clear()


def _carriers(model, heads, ends, deform):
    """(J,) the chain bone whose radius each bone's vertices count for (-1: none): a limb's chain bone itself;
    another deform bone, the chain bone along whose joint segment it lies (_ALONG), the nearest."""
    chain = np.array(sorted(b for limb in model.limbs.values() for b in limb.bones), dtype=np.int64)
    carrier = np.full(len(model.names), -1, dtype=np.int64)
    carrier[chain] = chain
    others = np.nonzero(deform & (carrier < 0))[0]
    if not others.size or not chain.size:
        return carrier
    a, b = heads[chain], ends[chain]  # (C,3)
    off = np.maximum(_point_segment(heads[others][:, None], a, b), _point_segment(ends[others][:, None], a, b))
    length = np.linalg.norm(b - a, axis=-1)
    off = np.where(off <= _ALONG * length, off, np.inf)  # (O,C)
    near = np.isfinite(off).any(axis=1)
    carrier[others[near]] = chain[np.argmin(off[near], axis=1)]
    return carrier


def _point_segment(points, a, b):
    """Distances (...,) of ``points`` (...,3) from segments a -> b (...,3)."""
    d = b - a
    t = np.clip(np.sum((points - a) * d, axis=-1) / np.maximum(np.sum(d * d, axis=-1), 1e-300), 0.0, 1.0)
    return np.linalg.norm(points - (a + t[..., None] * d), axis=-1)


def _deform_flags(obj):
    """(J,) bool: which bones deform (obj.data.bones order)."""
    bones = obj.data.bones
    flags = np.empty(len(bones), dtype=bool)
    bones.foreach_get("use_deform", flags)
    return flags


def _rest_positions(mesh):
    """(n,3) the mesh's undeformed vertex positions in its object space."""
    vertices = mesh.data.vertices
    co = np.empty(len(vertices) * 3, dtype=np.float32)
    vertices.foreach_get("co", co)
    return co.reshape(-1, 3).astype(np.float64)


def _mesh_weights(mesh):
    """(fingerprint, (vertex, group, weight)): every vertex group membership of the mesh's vertices, read once
    while its vertices and vertex groups stay the same."""
    data = mesh.data
    co = np.empty(len(data.vertices) * 3, dtype=np.float32)
    data.vertices.foreach_get("co", co)
    fingerprint = (getattr(mesh, "session_uid", None), getattr(data, "session_uid", None), co.size, hash(co.tobytes()),
                   tuple(g.name for g in mesh.vertex_groups))
    kept = _weights.get(mesh.name)
    if kept is not None and kept[0] == fingerprint:
        _weights.move_to_end(mesh.name)
        return kept
    vertex, group, weight = [], [], []
    for v in data.vertices:
        for g in v.groups:
            vertex.append(v.index)
            group.append(g.group)
            weight.append(g.weight)
    arrays = (np.array(vertex, dtype=np.int64), np.array(group, dtype=np.int64), np.array(weight, dtype=np.float64))
    _remember(_weights, mesh.name, (fingerprint, arrays))
    return fingerprint, arrays


def _remember(store, name, value):
    store[name] = value
    store.move_to_end(name)
    while len(store) > _CAPACITY:
        store.popitem(last=False)
