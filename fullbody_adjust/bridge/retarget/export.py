# SPDX-License-Identifier: GPL-3.0-or-later
"""A retargeted clip written as a file a game engine imports as it is (``retarget --output-dir DIR --format``):
the target file as a .blend, or the target armature (with the meshes it deforms, unless armature only) and its
new action through Blender's own FBX or glTF (binary .glb) exporter.

The settings, chosen so Unreal, Unity and Godot import the file without fixes:

- what: the target armature, selected alone or with the meshes its Armature modifier binds (or parented to it);
  only its deforming bones and their parents (the skeleton an engine skins with; control and mechanism bones of
  a rig are no use there). No leaf bones (FBX). The meshes go at rest, bound to their bones (the skinning is the
  engine's), their other modifiers not applied, so their shape keys go along.
- motion: the new action only, baked: one key per frame on every exported bone over the action's frames
  (FBX: no curve simplification; glTF: sampled, no key left out as redundant), so the engine plays what was
  solved and nothing is fitted again. The animation (FBX's take, glTF's animation) is named after the clip; glTF's
  starts at time 0.
- units: FBX says its unit is the scene's (1 Blender unit = 1 m in a metric scene) in the file's unit scale and
  moves nothing (``FBX_SCALE_UNITS``): Unity imports the character at scale 1, Unreal converts metres to its
  centimetres. glTF is in metres by its specification, and Blender's exporter takes a Blender unit for a metre:
  in a scene of another unit scale (centimetres: 0.01) the character is written under a root node
  '<armature>_metres' scaled by the unit scale, so it comes out in metres.
- axes: FBX's Y up, -Z forward, written in the file's axis system (engines convert on import); glTF's +Y up, as
  its specification asks. Bone axes are Blender's (primary Y, secondary X).
"""

import os

import addon_utils
import bpy

from ..errors import AdjustError
from ..files import save_blend

FORMATS = ("blend", "fbx", "glb")
_EXPORTERS = {"fbx": "io_scene_fbx", "glb": "io_scene_gltf2"}


def output_name(name, file_format):
    """The file a clip named ``name`` is written to in --output-dir."""
    return f"{name}.{file_format}"


def write_clip(context, target_obj, action, path, file_format="blend", *, meshes=True):
    """Write the clip: the whole current file as a .blend, or ``target_obj`` (with the meshes it deforms when
    ``meshes``) and ``action`` through the FBX or glTF exporter. AdjustError (one line) when the exporter fails."""
    if file_format == "blend":
        save_blend(path)
        return
    if file_format not in _EXPORTERS:
        raise AdjustError(f"Unknown output format '{file_format}' (use {', '.join(FORMATS)})")
    if not addon_utils.check(_EXPORTERS[file_format])[1]:
        addon_utils.enable(_EXPORTERS[file_format], default_set=False)
    scene = context.scene
    kept = (scene.frame_start, scene.frame_end, context.view_layer.objects.active,
            [ob for ob in context.view_layer.objects if ob.select_get()])
    first, last = (int(round(f)) for f in action.frame_range)
    try:
        if context.object is not None and context.object.mode != 'OBJECT':
            bpy.ops.object.mode_set(mode='OBJECT')
        exported = [target_obj, *(deformed_meshes(target_obj) if meshes else [])]
        scene.frame_start, scene.frame_end = first, last  # FBX bakes the scene's frame range
        if file_format == "fbx":
            _select(exported, context)
            _export_fbx(path, meshes, scene, action.name)
        else:
            root, parented = _metres_root(scene, exported, target_obj.name)
            _select(exported + ([root] if root is not None else []), context)
            try:
                _export_glb(path, meshes, action.name)
            finally:
                _remove_root(root, parented)
    except RuntimeError as ex:
        raise AdjustError(f"Cannot write {path}: {' '.join(str(ex).split())}") from None
    finally:
        scene.frame_start, scene.frame_end = kept[0], kept[1]
        _select(kept[3], context, active=kept[2])


def deformed_meshes(armature):
    """The meshes ``armature`` deforms (an Armature modifier bound to it) or carries (parented to it)."""
    return [ob for ob in bpy.data.objects if ob.type == 'MESH' and (
        ob.parent == armature or any(m.type == 'ARMATURE' and m.object == armature for m in ob.modifiers))]


def _metres_root(scene, objects, name):
    """In a scene whose unit is not the metre: (an empty scaled by the unit scale at the origin, made parent of
    the ``objects`` that had none so their world transforms become metres, {each of them: its parent inverse});
    (None, {}) in a metre scene."""
    unit = scene.unit_settings.scale_length
    if abs(unit - 1.0) <= 1e-9:
        return None, {}
    root = bpy.data.objects.new(f"{name}_metres", None)
    scene.collection.objects.link(root)
    root.scale = (unit, unit, unit)
    parented = {}
    for ob in objects:
        if ob.parent is None:
            parented[ob] = ob.matrix_parent_inverse.copy()  # unused without a parent, but given back
            ob.parent = root
            ob.matrix_parent_inverse.identity()
    return root, parented


def _remove_root(root, parented):
    """Undo _metres_root."""
    for ob, inverse in parented.items():
        ob.parent = None
        ob.matrix_parent_inverse = inverse
    if root is not None:
        bpy.data.objects.remove(root)


def _select(objects, context, active=None):
    layer = context.view_layer
    for ob in layer.objects:
        ob.select_set(False)
    for ob in objects:
        if ob.name in layer.objects:
            ob.select_set(True)
    layer.objects.active = active if active is not None else (objects[0] if objects else None)


def _export_fbx(path, meshes, scene, name):
    """The FBX take is named after the scene whose frames it bakes: the scene goes by the clip's name meanwhile, so
    the engine's animation is named after the clip (as glTF's is), not 'Scene' in every file."""
    kept, scene.name = scene.name, name
    try:
        _fbx(path, meshes)
    finally:
        scene.name = kept


def _fbx(path, meshes):
    bpy.ops.export_scene.fbx(
        filepath=os.path.abspath(path), use_selection=True,
        object_types={'ARMATURE', 'MESH'} if meshes else {'ARMATURE'},
        use_mesh_modifiers=False,  # applied modifiers would drop the shape keys
        use_armature_deform_only=True, add_leaf_bones=False, primary_bone_axis='Y', secondary_bone_axis='X',
        armature_nodetype='NULL',
        apply_unit_scale=True, apply_scale_options='FBX_SCALE_UNITS', global_scale=1.0,
        axis_forward='-Z', axis_up='Y', bake_space_transform=False,
        bake_anim=True, bake_anim_use_all_bones=True, bake_anim_use_nla_strips=False,
        bake_anim_use_all_actions=False, bake_anim_force_startend_keying=True, bake_anim_step=1.0,
        bake_anim_simplify_factor=0.0, path_mode='AUTO', embed_textures=False)


def _export_glb(path, meshes, name):
    bpy.ops.export_scene.gltf(
        filepath=os.path.abspath(path), export_format='GLB', use_selection=True, export_yup=True,
        export_apply=False, export_skins=meshes, export_def_bones=True, export_leaf_bone=False,
        export_materials='EXPORT' if meshes else 'NONE',
        export_animations=True, export_animation_mode='ACTIVE_ACTIONS',
        export_nla_strips_merged_animation_name=name, export_force_sampling=True, export_frame_step=1,
        export_frame_range=False, export_anim_slide_to_zero=True, export_optimize_animation_size=False,
        export_reset_pose_bones=True, export_rest_position_armature=True)
