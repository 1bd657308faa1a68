"""Mapping rigs that went through Blender's own glTF and FBX exporters and importers (default settings), as the
characters users bring do: the Rigify basic metarig with a skinned mesh, its bones renamed "Bone", "Bone.001", ...
(no side marker) or kept, turned to face -Y, +X, -X or +Y with the turn applied to the armature data. The
importers move the tails (glTF: its bone heuristic; FBX: along each bone's Y axis, leaf "_end" bones added), so
the map must come from the joints and the skeleton's own facing. Files are written to a temporary directory."""

import math

import bpy
import numpy as np
import pytest

from fullbody_adjust.bone_mapping import map_rig
from fullbody_adjust.bridge.rig.mapping import describe_armature

from .test_mapping import rigify_groups, rigify_metarig
from tests.test_mapping_rules import rename_map

FACINGS = {"-Y": 0.0, "+X": 90.0, "-X": -90.0, "+Y": 180.0}


def skinned_metarig(facing, unnamed):
    """The basic metarig turned to ``facing`` (applied to its data), a mesh skinned to it (a vertex at every
    bone's head, each in its bone's group). Returns (armature, {original bone name: name now})."""
    obj = rigify_metarig()
    obj.rotation_euler = (0.0, 0.0, math.radians(FACINGS[facing]))
    bpy.ops.object.transform_apply(location=False, rotation=True, scale=False)
    names = {b.name: b.name for b in obj.data.bones}
    if unnamed:
        for k, bone in enumerate(list(obj.data.bones)):
            new = "Bone" if k == 0 else f"Bone.{k:03d}"
            names[bone.name] = new
            bone.name = new
    mesh = bpy.data.meshes.new("Body")
    corners = 0.01 * np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    points = [tuple(np.array(b.head_local) + c) for b in obj.data.bones for c in corners]
    mesh.from_pydata(points, [], [(3 * k, 3 * k + 1, 3 * k + 2) for k in range(len(obj.data.bones))])
    body = bpy.data.objects.new("Body", mesh)
    bpy.context.scene.collection.objects.link(body)
    for k, bone in enumerate(obj.data.bones):
        body.vertex_groups.new(name=bone.name).add([3 * k, 3 * k + 1, 3 * k + 2], 1.0, 'REPLACE')
    body.parent = obj
    body.modifiers.new("Armature", 'ARMATURE').object = obj
    return obj, names


def round_trip(tmp_path, fmt):
    """Export the scene and import it into an empty one with the importer's defaults; the armature."""
    path = tmp_path / f"rig.{fmt}"
    if fmt == "glb":
        bpy.ops.export_scene.gltf(filepath=str(path), export_format='GLB')
    else:
        bpy.ops.export_scene.fbx(filepath=str(path))
    bpy.ops.wm.read_homefile(use_empty=True)
    if fmt == "glb":
        bpy.ops.import_scene.gltf(filepath=str(path))
    else:
        bpy.ops.import_scene.fbx(filepath=str(path))
    return next(o for o in bpy.data.objects if o.type == 'ARMATURE')


def tail_misses(obj):
    """How many bones with one child have their tail off that child's head (more than 1 mm)."""
    return sum(1 for b in obj.data.bones if len(b.children) == 1
               and (b.tail_local - b.children[0].head_local).length > 1e-3)


@pytest.mark.parametrize("fmt", ["glb", "fbx"])
@pytest.mark.parametrize("facing", FACINGS)
def test_unnamed_rig_after_import_maps_with_its_own_left(tmp_path, fmt, facing):
    obj, names = skinned_metarig(facing, unnamed=True)
    expected = rename_map(rigify_groups(), list(names), list(names.values()))
    imported = round_trip(tmp_path, fmt)
    bone_map = map_rig(describe_armature(imported))
    assert bone_map == expected and bone_map.source == "detected from the hierarchy"
    # The character's left, from its facing in the world: the left hand lies on up x forward.
    world = imported.matrix_world
    heads = {b.name: np.array(world @ b.head_local) for b in imported.data.bones}
    a = math.radians(FACINGS[facing])
    left = np.array([math.cos(a), math.sin(a), 0.0])  # -Y facing: +X; turned by a about z
    assert (heads[bone_map.bones("hand.L")[0]] - heads[bone_map.bones("hand.R")[0]]) @ left > 0
    assert (heads[bone_map.bones("foot.L")[0]] - heads[bone_map.bones("foot.R")[0]]) @ left > 0


def scramble_tails(obj, seed=0):
    """Point every bone along a random direction (heads kept), as rigs whose bone axes do not follow the limb
    (bones along X, rolled bones) come: the exporters write those orientations, so after import no tail says
    where the next joint is."""
    rng = np.random.default_rng(seed)
    bpy.context.view_layer.objects.active = obj
    bpy.ops.object.mode_set(mode='EDIT')
    for bone in obj.data.edit_bones:
        bone.use_connect = False
    for bone in obj.data.edit_bones:
        direction = rng.normal(size=3)
        bone.tail = np.array(bone.head) + bone.length * direction / np.linalg.norm(direction)
    bpy.ops.object.mode_set(mode='OBJECT')


@pytest.mark.parametrize("fmt", ["glb", "fbx"])
@pytest.mark.parametrize("facing", ["+X", "-Y"])
def test_bone_axes_that_ignore_the_limbs_change_nothing(tmp_path, fmt, facing):
    obj, names = skinned_metarig(facing, unnamed=True)
    scramble_tails(obj)
    expected = rename_map(rigify_groups(), list(names), list(names.values()))
    imported = round_trip(tmp_path, fmt)
    assert tail_misses(imported) >= 14  # every one of the metarig's 14 bones with one child
    assert map_rig(describe_armature(imported)) == expected


@pytest.mark.parametrize("fmt", ["glb", "fbx"])
@pytest.mark.parametrize("facing", ["+X", "+Y"])
def test_named_rig_after_import_maps_by_its_names(tmp_path, fmt, facing):
    skinned_metarig(facing, unnamed=False)
    imported = round_trip(tmp_path, fmt)
    bone_map = map_rig(describe_armature(imported))
    assert bone_map == rigify_groups() and bone_map.source == "Rigify metarig"
