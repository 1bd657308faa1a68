"""Soles on the floor, measured on the mesh (bridge/retarget/soles.py): a character's mesh feet stand on the
floor after a retarget, neither sinking nor floating, and the report's contact and floor figures are the ones
measured here on the written file's evaluated mesh vertices.

The character is built here: the Rigify basic metarig with a box under each foot whose sole lies 3 cm below
the floor the foot's joints stand on (a thick shoe), weighted by hand to the foot and toe bones; used as it
is, and after a round trip through Blender's own glTF and FBX exporters and importers (default settings:
the glTF importer's tails and the FBX importer's bone axes are theirs, and the armature's object scale and
rotation come from the file). The source is the CMU walk (tests/data/mocap)."""

import bpy
import numpy as np
import pytest

from fullbody_adjust.bridge.writing import keyframes
from fullbody_adjust.bridge.rig import mapping
from fullbody_adjust.bridge.retarget import run as retarget

from .test_retarget import FRAMES, add_metarig, import_clip, select_only, source_foot_points

SOLE = 0.03  # the shoe's sole below the floor the metarig's foot joints stand on


def add_shoes(rig, shin_share=0.0, sole=SOLE):
    """A box per foot, from the heel to past the toes and ``sole`` below the lowest foot joint, its heel
    half weighted to the foot bone (and ``shin_share`` of its heel end to the shin, as skinning often shares
    a heel with the shin) and its toe half to the toe bone, deformed by an Armature modifier."""
    world = np.array(rig.matrix_world)
    meshes = []
    for side in ("L", "R"):
        foot, toe = rig.data.bones[f"foot.{side}"], rig.data.bones[f"toe.{side}"]
        ankle = world @ np.r_[np.array(foot.head_local), 1.0]
        ball = world @ np.r_[np.array(toe.head_local), 1.0]
        tip = world @ np.r_[np.array(toe.tail_local), 1.0]
        low = min(ankle[2], ball[2], tip[2]) - sole
        x0, x1 = ankle[0] - 0.05, ankle[0] + 0.05
        y_heel, y_ball, y_tip = ankle[1] + 0.06, ball[1], tip[1] - 0.02
        verts, weights = [], []
        for y, bone in ((y_heel, foot.name), (y_ball, foot.name), (y_ball, toe.name), (y_tip, toe.name)):
            for x in (x0, x1):
                for z in (low, ankle[2]):
                    verts.append((x, y, z))
                    weights.append(bone)
        faces = [(0, 1, 3, 2), (4, 5, 7, 6), (8, 9, 11, 10), (12, 13, 15, 14), (0, 2, 6, 4), (1, 3, 7, 5),
                 (8, 10, 14, 12), (9, 11, 15, 13)]
        mesh = bpy.data.meshes.new(f"Shoe.{side}")
        mesh.from_pydata(verts, [], faces)
        obj = bpy.data.objects.new(f"Shoe.{side}", mesh)
        bpy.context.scene.collection.objects.link(obj)
        for name in (foot.name, toe.name):
            group = obj.vertex_groups.new(name=name)
            group.add([i for i, b in enumerate(weights) if b == name], 1.0, 'REPLACE')
        if shin_share:
            heel = [0, 1, 2, 3]  # the heel end's four vertices
            obj.vertex_groups[foot.name].add(heel, 1.0 - shin_share, 'REPLACE')
            obj.vertex_groups.new(name=f"shin.{side}").add(heel, shin_share, 'REPLACE')
        obj.parent = rig
        obj.matrix_parent_inverse = np.linalg.inv(world).T.tolist()
        modifier = obj.modifiers.new("Armature", 'ARMATURE')
        modifier.object = rig
        meshes.append(obj)
    bpy.context.view_layer.update()
    return meshes


def round_trip(tmp_path, rig, fmt):
    """The character exported with Blender's glTF or FBX exporter and imported back (default settings):
    (the imported armature, its meshes)."""
    path = tmp_path / ("hero.glb" if fmt == "gltf" else "hero.fbx")
    select_only(rig, *[o for o in bpy.data.objects if o.parent == rig], active=rig)
    if fmt == "gltf":
        bpy.ops.export_scene.gltf(filepath=str(path), use_selection=True, export_animations=False)
    else:
        bpy.ops.export_scene.fbx(filepath=str(path), use_selection=True, bake_anim=False)
    for ob in [rig] + [o for o in bpy.data.objects if o.parent == rig]:
        bpy.data.objects.remove(ob)
    before = set(bpy.data.objects)
    if fmt == "gltf":
        bpy.ops.import_scene.gltf(filepath=str(path))
    else:
        bpy.ops.import_scene.fbx(filepath=str(path))
    new = [o for o in bpy.data.objects if o not in before]
    arm = next(o for o in new if o.type == 'ARMATURE')
    return arm, [o for o in new if o.type == 'MESH' and any(m.type == 'ARMATURE' for m in o.modifiers)]


def mesh_soles(rig, meshes, frames):
    """{foot: lowest world z (F,) and world vertices (F,V,3)} of the shoes' vertices, evaluated by Blender."""
    out = {}
    for side, foot in (("L", "foot.L"), ("R", "foot.R")):
        obj = next(m for m in meshes if f"Shoe.{side}" in m.name)
        points = []
        for f in frames:
            bpy.context.scene.frame_set(int(f))
            depsgraph = bpy.context.evaluated_depsgraph_get()
            evaluated = obj.evaluated_get(depsgraph)
            mesh = evaluated.to_mesh()
            co = np.empty(3 * len(mesh.vertices), dtype=np.float32)
            mesh.vertices.foreach_get("co", co)
            world = np.array(evaluated.matrix_world)
            points.append(co.reshape(-1, 3) @ world[:3, :3].T + world[:3, 3])
            evaluated.to_mesh_clear()
        out[foot] = np.array(points)
    return out


def ball_heads(rig, frames):
    """{foot: world head (F,3) of its toe bone (the ball of the foot)}, evaluated by Blender."""
    bone_map = mapping.load_map(rig)
    toes = {foot: next(c for c in rig.pose.bones[bone_map.bones(foot)[0]].children if "toe" in c.name.lower())
            for foot in ("foot.L", "foot.R")}
    out = {foot: [] for foot in toes}
    for f in frames:
        bpy.context.scene.frame_set(int(f))
        for foot, toe in toes.items():
            out[foot].append(np.array(rig.matrix_world @ toe.head))
    return {foot: np.array(points) for foot, points in out.items()}


def ground_runs(outcome, effector):
    return [(c["start"], c["stop"]) for c in outcome.contact_report["effectors"][effector]["contacts"]
            if c["kind"] == "ground"]


@pytest.mark.parametrize("fmt, shin_share", [(None, 0.0), ("gltf", 0.0), ("fbx", 0.0), (None, 0.5)])
def test_mesh_soles_stand_on_the_floor_and_the_report_says_so(tmp_path, fmt, shin_share):
    """On planted frames the shoes' lowest vertices are within 10 mm of the floor (p95) and never more than
    5 mm below it on any frame; the foot's stillest point (a shoe vertex or the ball of the foot: the toe
    bone's head, which the foot turns about as its heel lifts) slides under 5 mm per contact (p95); the report's
    floor is the source's, its contact error, sliding and below-the-floor count those measured here on the mesh
    within 1 mm. The soles lie 3 cm below the joints: a floor measured on the joints would sink them that far. With
    the heels half on the shins they ride on the knees too, as the solve bends them."""
    rig = add_metarig(1.1)
    add_shoes(rig, shin_share)
    if fmt:
        rig, meshes = round_trip(tmp_path, rig, fmt)
    else:
        meshes = [o for o in bpy.data.objects if o.type == 'MESH']
    source = import_clip()
    select_only(rig)
    outcome = retarget.retarget(bpy.context, source, rig, *FRAMES)
    frames = outcome.frames.astype(int)
    floor = outcome.contact_report["floor"]
    soles = mesh_soles(rig, meshes, frames)
    balls = ball_heads(rig, frames)
    planted = []
    for effector, points in soles.items():
        lowest = points[..., 2].min(axis=1) - floor
        assert lowest.min() > -5e-3, effector
        runs = ground_runs(outcome, effector)
        assert runs, effector
        on = np.concatenate([lowest[a:b] for a, b in runs])
        planted.append(on)
        foot = np.concatenate([points, balls[effector][:, None]], axis=1)
        slid = [np.linalg.norm(np.diff(foot[a:b, :, :2], axis=0), axis=-1).min(axis=1).sum() for a, b in runs]
        reported = outcome.contact_report["effectors"][effector]
        assert np.percentile(slid, 95) < 5e-3, effector
        errors = np.concatenate([np.abs(points[a:b, :, 2].min(axis=1) - floor) for a, b in
                                 [(c["start"], c["stop"]) for c in reported["contacts"]]])
        assert reported["contact_error"]["max"] == pytest.approx(errors.max(), abs=1e-3)
        assert reported["sliding"]["p95"] == pytest.approx(np.percentile(slid, 95), abs=1e-3)
        assert reported["deepest_below_floor"] == pytest.approx(max(0.0, -lowest.min()), abs=1e-3)
    planted = np.concatenate(planted)
    assert len(planted) > 0.3 * len(frames)
    assert np.percentile(np.abs(planted), 95) < 10e-3
    # The figures speak of the mesh, not the joints: the shoes' soles are what rests on the floor.
    bone_map = mapping.load_map(rig)
    foot = rig.pose.bones[bone_map.bones("foot.L")[0]]
    runs = ground_runs(outcome, "foot.L")
    ankle = []
    for a, b in runs:
        for f in frames[a:b]:
            bpy.context.scene.frame_set(int(f))
            ankle.append((rig.matrix_world @ foot.head)[2] - floor)
    assert np.median(ankle) > np.median(soles["foot.L"][0, :, 2].max() - soles["foot.L"][0, :, 2].min()) * 0.5



def in_place(source):
    """The clip with its hips' travel over the floor taken out of the root's location keys (an in-place clip:
    the planted foot slides back under the body as on a treadmill)."""
    root = source.data.bones[0]
    first, last = (int(round(f)) for f in source.animation_data.action.frame_range)
    frames = np.arange(first, last + 1)
    travel = []
    for f in frames:
        bpy.context.scene.frame_set(int(f))
        travel.append(np.array(source.matrix_world @ source.pose.bones[root.name].head))
    travel = np.array(travel) - travel[0]
    travel[:, 2] = 0.0
    local = travel @ np.array(source.matrix_world.to_3x3().inverted()).T @ np.array(root.matrix_local.to_3x3())
    for fc in keyframes.animating_fcurves(source):
        if fc.data_path != f'pose.bones["{root.name}"].location':
            continue
        for key in fc.keyframe_points:
            k = int(np.clip(np.searchsorted(frames, int(round(key.co[0]))), 0, len(frames) - 1))
            for point in (key.co, key.handle_left, key.handle_right):
                point[1] -= local[k, fc.array_index]
        fc.update()
    bpy.context.view_layer.update()
    return source


def test_an_in_place_walk_of_a_game_character_stands_on_the_ground_plane():
    """The walk made in place, and its skeleton standing 6 cm above the world's ground plane (as a game
    character's joints stand inside feet we do not see): its stances slide, so they are not held still, yet
    the shoes stand on z = 0: on the frames where the source's sole is lowest (each foot's lower half) within
    10 mm of it (p95), never more than 5 mm below it (measured on the evaluated mesh; before, the transferred
    pose floated them 6 cm over the floor its joints made)."""
    rig = add_metarig(1.1)
    meshes = add_shoes(rig)
    source = in_place(import_clip())
    source.location.z += 0.06 - float(np.percentile(np.minimum(*(
        source_foot_points(source, np.arange(*FRAMES), e)[..., 2].min(axis=1) for e in ("foot.L", "foot.R"))), 2))
    bpy.context.view_layer.update()
    frames = np.arange(*FRAMES)
    bpy.context.scene.frame_set(int(frames[0]))
    start = np.array(source.matrix_world @ source.pose.bones[0].head)
    bpy.context.scene.frame_set(int(frames[-1]))
    assert np.linalg.norm((np.array(source.matrix_world @ source.pose.bones[0].head) - start)[:2]) < 0.05
    select_only(rig)
    outcome = retarget.retarget(bpy.context, source, rig, *FRAMES)
    frames = outcome.frames.astype(int)
    floor = outcome.contact_report["floor"]
    assert floor == 0.0
    soles = mesh_soles(rig, meshes, frames)
    for effector, points in soles.items():
        held = sum(c["stop"] - c["start"] for c in outcome.contact_report["effectors"][effector]["contacts"])
        assert held < 0.1 * len(frames)  # the stances slide: not held
        source_low = source_foot_points(source, frames, effector)[..., 2].min(axis=1)
        lowest = points[..., 2].min(axis=1) - floor
        assert lowest.min() > -5e-3
        resting = source_low <= np.percentile(source_low, 50)
        assert np.percentile(np.abs(lowest[resting]), 95) < 10e-3
