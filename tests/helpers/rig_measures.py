"""Measurements of a written result, taken from Blender's EVALUATION (depsgraph, frame_set, evaluated meshes),
independent of the solver's own numbers; for tests/blender/test_real_rigs.py and bench/real_rigs.py.

Joints are bone HEADS (a bone's end is its chain child's head), never tails. Positions come out in world units;
callers convert with the rig's metres per unit. The definitions:

- rotation change of a bone: the angle (degrees) of the rotation taking its evaluated LOCAL orientation (its
  armature-space matrix relative to its parent's, scale removed) in one state to the other;
- keyed bones: the bones whose F-Curves (in the action animating the armature) were added or changed;
- sole height of a foot: the lowest evaluated world vertex of the meshes weighted >= 0.5 to the foot's ankle and
  ball bones together (any weight where none reaches 0.5);
- plant (of a source foot): frames where the ankle or the ball of the foot moves slower than 0.2 m/s within
  6 cm of the floor (the clip's lowest ankle or ball height), in runs of at least 0.1 s;
- slide: on every planted frame, the horizontal distance of the planted joint (ball or ankle, whichever the source
  planted; the ball when both, if the rig has one) from where it was on the plant's first frame;
- limb direction angle: the angle between a limb segment's direction (upper arm, forearm, thigh, shin) in the
  result and in the source, each expressed in its own body's frame of the same frame (left = hips line, up = +Z);
- heading error: the angle between the result's hips travel, expressed relative to the way its hips face (the
  normal of the hip joints' line, averaged over the clip), and the source's hips travel relative to the source's
  hips the same way (both horizontal). The hips, not an axis declared for the rig: a skeleton may stand turned from
  its object's axes (GDQuest's is some 12 degrees off -Y at rest, its toes, hips and shoulders alike);
- pop frame: a frame on which any of the hips, upper arm, forearm, thigh or shin bones' world orientation turned
  more than POP_DEGREES since the previous frame (compared with the source's own count on the same frames).
"""

from __future__ import annotations

import bpy
import numpy as np

from tests.helpers.blender_data import bulk, evaluated

POP_DEGREES = 30.0
POP_ROLES = ("hips", "shoulder", "elbow", "hip", "knee")  # the bones starting there: hips, upper arm, forearm,
# thigh, shin (feet and toes turn 30+ degrees a frame at toe-off in a 24 fps walk, hands flick)
PLANT_SPEED = 0.2  # m/s
PLANT_HEIGHT = 0.06  # m above the floor
PLANT_SECONDS = 0.1
SEGMENTS = (("upper_arm", "shoulder", "elbow"), ("forearm", "elbow", "wrist"), ("thigh", "hip", "knee"),
            ("shin", "knee", "ankle"))
UP = np.array([0.0, 0.0, 1.0])


def pose_matrices(obj):
    """{bone: (4,4) evaluated armature-space matrix}."""
    ev = evaluated(obj)
    matrices = bulk(ev.pose.bones, "matrix", (4, 4)).transpose(0, 2, 1)
    return {pb.name: m for pb, m in zip(ev.pose.bones, matrices)}


def world_heads(obj, bones=None):
    """(n,3) evaluated world positions of the heads of ``bones`` (all when None), in order."""
    ev = evaluated(obj)
    heads = bulk(ev.pose.bones, "head", (3,))
    index = {pb.name: i for i, pb in enumerate(ev.pose.bones)}
    names = list(index) if bones is None else list(bones)
    world = np.array(ev.matrix_world, dtype=np.float64)
    return heads[[index[b] for b in names]] @ world[:3, :3].T + world[:3, 3]


def _unit_rotation(m):
    """The rotation of a 3x3 matrix with its per-column scale removed."""
    m = np.asarray(m, dtype=np.float64)
    return m / np.linalg.norm(m, axis=-2, keepdims=True)


def local_rotations(obj):
    """{bone: (3,3)} each bone's evaluated orientation relative to its parent's (armature space)."""
    matrices = pose_matrices(obj)
    out = {}
    for bone in obj.data.bones:
        m = _unit_rotation(matrices[bone.name][:3, :3])
        if bone.parent is not None:
            m = _unit_rotation(matrices[bone.parent.name][:3, :3]).T @ m
        out[bone.name] = m
    return out


def angle_between_rotations(a, b):
    """Degrees of the rotation taking a to b ((..,3,3) each)."""
    rel = np.swapaxes(a, -1, -2) @ b
    cos = (np.trace(rel, axis1=-2, axis2=-1) - 1.0) / 2.0
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def rotation_changes(before, after):
    """{bone: degrees} between two local_rotations states."""
    return {bone: float(angle_between_rotations(before[bone], after[bone])) for bone in before}


# --- keys -----------------------------------------------------------------------------------------------------


def animating_fcurves(obj):
    """The F-Curves of the action animating ``obj`` (legacy action.fcurves before 4.4, the slot's channelbag
    after)."""
    anim = obj.animation_data
    if anim is None or anim.action is None:
        return []
    if bpy.app.version < (4, 4, 0):
        return list(anim.action.fcurves)
    if anim.action_slot is None:
        return []
    from bpy_extras import anim_utils

    bag = anim_utils.action_get_channelbag_for_slot(anim.action, anim.action_slot)
    return list(bag.fcurves) if bag is not None else []


def assign_action(obj, action):
    """Make ``action`` animate ``obj`` (its first slot on 4.4+, where assigning leaves none chosen)."""
    anim = obj.animation_data or obj.animation_data_create()
    anim.action = action
    if bpy.app.version >= (4, 4, 0) and anim.action_slot is None and len(action.slots):
        anim.action_slot = action.slots[0]
    bpy.context.view_layer.update()


def shift_keys(obj, frames):
    """Move every key of ``obj``'s action (its slot's F-Curves) by ``frames``."""
    if not frames:
        return
    curves = animating_fcurves(obj)
    for fc in curves:
        for prop in ("co", "handle_left", "handle_right"):
            values = np.empty(2 * len(fc.keyframe_points))
            fc.keyframe_points.foreach_get(prop, values)
            values[0::2] += frames
            fc.keyframe_points.foreach_set(prop, values)
        fc.update()
    bpy.context.view_layer.update()


def keys_snapshot(obj):
    """{(data_path, index): keyframe coordinates as bytes}."""
    out = {}
    for fc in animating_fcurves(obj):
        co = np.empty(2 * len(fc.keyframe_points), dtype=np.float32)
        fc.keyframe_points.foreach_get("co", co)
        out[(fc.data_path, fc.array_index)] = co.tobytes()
    return out


def _bone_of(data_path):
    if data_path.startswith('pose.bones["'):
        return data_path[len('pose.bones["'):].split('"]', 1)[0]
    return None


def keyed_bones(before, after):
    """The bones whose F-Curves are new or changed between two keys_snapshot states (sorted)."""
    changed = {path for (path, _), co in after.items() if before.get((path, _)) != co}
    return sorted({_bone_of(p) or f"<{p}>" for p in changed})


# --- meshes ---------------------------------------------------------------------------------------------------


def mesh_vertices(meshes):
    """(n,3) evaluated world vertex positions of ``meshes`` (deformed by their modifiers), concatenated."""
    bpy.context.view_layer.update()
    depsgraph = bpy.context.evaluated_depsgraph_get()
    out = []
    for ob in meshes:
        ev = ob.evaluated_get(depsgraph)
        mesh = ev.to_mesh()
        co = np.empty(3 * len(mesh.vertices), dtype=np.float32)
        mesh.vertices.foreach_get("co", co)
        world = np.array(ev.matrix_world, dtype=np.float64)
        out.append(co.reshape(-1, 3).astype(np.float64) @ world[:3, :3].T + world[:3, 3])
        ev.to_mesh_clear()
    return np.concatenate(out) if out else np.zeros((0, 3))


def sole_heights(rig, side, verts):
    """The sole height of the rig's ``side`` foot ('L' or 'R') on each sampled frame (``verts``: per frame the
    evaluated world vertices of rig.meshes, stacked), in metres; None where no mesh is weighted to the foot."""
    foot_bones = {rig.joints[f"ankle.{side}"], rig.joints.get(f"ball.{side}")} - {None}
    masks = foot_vertex_masks(rig.meshes, foot_bones)
    mask = np.concatenate(masks) if masks else None
    if mask is None or not mask.any():
        return None
    return np.array([v[mask, 2].min() for v in verts]) * rig.metres_per_unit


def foot_vertex_masks(meshes, bones):
    """Per mesh, the (n,) bool mask of vertices weighted to ``bones`` together: >= 0.5 where any vertex of the
    meshes reaches it, else > 0. Masks follow mesh_vertices' order."""
    weights = []
    for ob in meshes:
        index = {g.index for g in ob.vertex_groups if g.name in bones}
        w = np.zeros(len(ob.data.vertices))
        for v in ob.data.vertices:
            w[v.index] = sum(g.weight for g in v.groups if g.group in index)
        weights.append(w)
    if not weights:
        return []
    level = 0.5 if max(float(w.max(initial=0.0)) for w in weights) >= 0.5 else 1e-6
    return [w >= level for w in weights]


def sole_height(vertices, mask):
    """Lowest world z of the masked vertices (NaN without any)."""
    return float(vertices[mask, 2].min()) if mask.any() else float("nan")


def vertices_inside(vertices, lo, hi):
    return int(np.all((vertices > lo) & (vertices < hi), axis=1).sum())


def box_bounds(box):
    """World (lo, hi) of a box mesh's evaluated vertices."""
    v = mesh_vertices([box])
    return v.min(axis=0), v.max(axis=0)


# --- motion ---------------------------------------------------------------------------------------------------


def sample(frames, tracks, meshes=()):
    """Step the scene through ``frames``; per frame, for each (obj, bones) of ``tracks`` the world heads (F,n,3) and
    world orientations (F,n,3,3); and the evaluated vertices of ``meshes`` (list of (F,v,3)).
    Returns (heads list, rotations list, vertices)."""
    scene = bpy.context.scene
    heads = [[] for _ in tracks]
    rots = [[] for _ in tracks]
    verts = []
    for frame in frames:
        scene.frame_set(int(frame))
        for k, (obj, bones) in enumerate(tracks):
            heads[k].append(world_heads(obj, bones))
            matrices = pose_matrices(obj)
            world = np.array(obj.matrix_world, dtype=np.float64)[:3, :3]
            rots[k].append(np.array([_unit_rotation(world @ matrices[b][:3, :3]) for b in bones]))
        if meshes:
            verts.append(mesh_vertices(meshes))
    return [np.array(h) for h in heads], [np.array(r) for r in rots], verts


def plants(ankle, ball, fps, metres_per_unit, floor=None):
    """(F,) bool planted mask and (F,) planted joint ('ball' preferred, 'ankle') of one source foot from its world
    ankle and ball tracks (F,3) (ball may be None); the floor is ``floor`` (world z), by default the lowest ankle
    or ball height of this foot in the clip (pass the lowest of both feet where one foot may never come down)."""
    joints = {"ankle": ankle} if ball is None else {"ball": ball, "ankle": ankle}
    if floor is None:
        floor = min(float(p[:, 2].min()) for p in joints.values())
    held = {}
    for name, p in joints.items():
        speed = np.zeros(len(p))
        step = np.linalg.norm(np.diff(p, axis=0), axis=1) * fps * metres_per_unit
        speed[1:] = step
        speed[0] = step[0] if len(step) else 0.0
        speed[1:-1] = np.minimum(step[:-1], step[1:])  # a frame holds if it holds towards either neighbour
        low = (p[:, 2] - floor) * metres_per_unit < PLANT_HEIGHT
        held[name] = _runs_at_least((speed < PLANT_SPEED) & low, int(np.ceil(PLANT_SECONDS * fps)))
    planted = np.zeros(len(ankle), dtype=bool)
    which = np.array([""] * len(ankle), dtype=object)
    for name in ("ankle", "ball"):  # the ball wins where both hold
        if name in held:
            planted |= held[name]
            which[held[name]] = name
    return planted, which


def _runs_at_least(mask, length):
    out = np.zeros_like(mask)
    start = None
    for i, m in enumerate(list(mask) + [False]):
        if m and start is None:
            start = i
        elif not m and start is not None:
            if i - start >= length:
                out[start:i] = True
            start = None
    return out


def slides(planted, which, points):
    """(k,) slide distances (world units) over the planted frames: ``points`` {'ankle': (F,3), 'ball': (F,3) or
    None}; a plant run restarts where the planted joint changes."""
    out = []
    anchor, joint_before = None, None
    for f in range(len(planted)):
        if not planted[f]:
            anchor = None
            continue
        joint = which[f] if points.get(which[f]) is not None else "ankle"
        if anchor is None or joint != joint_before:
            anchor = points[joint][f]
        joint_before = joint
        d = points[joint][f] - anchor
        out.append(float(np.hypot(d[0], d[1])))
    return np.array(out)


def body_frames(hip_left, hip_right):
    """(F,3,3) rows (left, forward, up) per frame from the world hip joints (F,3)."""
    left = hip_left - hip_right
    left[:, 2] = 0.0
    left /= np.linalg.norm(left, axis=1, keepdims=True)
    up = np.broadcast_to(UP, left.shape)
    forward = np.cross(left, up)  # as left = up x forward
    return np.stack([left, forward, up], axis=1)


def limb_direction_angles(joints, source_joints):
    """(F,k) degrees between the result's and the source's limb segments (SEGMENTS, both sides where both have
    the joints), each in its own body frame. ``joints``: {role: (F,3) or None} with roles like 'hip.L'."""
    frames = body_frames(joints["hip.L"], joints["hip.R"])
    source_frames = body_frames(source_joints["hip.L"], source_joints["hip.R"])
    angles = []
    for _, a, b in SEGMENTS:
        for side in ("L", "R"):
            pa, pb = joints.get(f"{a}.{side}"), joints.get(f"{b}.{side}")
            sa, sb = source_joints.get(f"{a}.{side}"), source_joints.get(f"{b}.{side}")
            if any(x is None for x in (pa, pb, sa, sb)):
                continue
            d = np.einsum("fij,fj->fi", frames, pb - pa)
            s = np.einsum("fij,fj->fi", source_frames, sb - sa)
            cos = np.sum(d * s, axis=1) / (np.linalg.norm(d, axis=1) * np.linalg.norm(s, axis=1))
            angles.append(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))
    return np.stack(angles, axis=1) if angles else np.zeros((len(frames), 0))


def _yaw(v):
    return float(np.degrees(np.arctan2(v[1], v[0])))


def heading_error(hips, facing, source_hips, source_facing):
    """Degrees (-180..180) between the result's travel relative to its facing and the source's travel relative to
    its facing (horizontal vectors)."""
    travel = hips[-1] - hips[0]
    source_travel = source_hips[-1] - source_hips[0]
    relative = _yaw(travel) - _yaw(facing)
    source_relative = _yaw(source_travel) - _yaw(source_facing)
    return float((relative - source_relative + 180.0) % 360.0 - 180.0)


def pop_frames(rotations, degrees=POP_DEGREES):
    """Frames (indices into the samples) where any bone's world orientation turned more than ``degrees`` since
    the previous sample: rotations (F,n,3,3)."""
    steps = angle_between_rotations(rotations[:-1], rotations[1:])  # (F-1,n)
    return [int(i) + 1 for i in np.nonzero((steps > degrees).any(axis=1))[0]]


def largest_step(rotations):
    steps = angle_between_rotations(rotations[:-1], rotations[1:])
    return float(steps.max()) if steps.size else 0.0
