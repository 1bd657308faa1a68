"""World joint positions per frame of the one armature of a file, read in a fresh Blender (the bpy module):

    python tests/helpers/joint_positions.py FILE OUT.json

FILE is a .blend (opened), or an .fbx or .glb imported by Blender's own importer into an empty scene. OUT.json
gets {"armature", "frames" (its action's, in order), "joints": {bone: [[x, y, z] per frame], in metres (world
units times the scene's unit scale)}, "meshes": names
of the mesh objects its Armature modifiers bind, "actions": names}. A separate process, so the import is in a
fresh file, and Blender 4.2's glTF importer (which crashed a long test process) runs alone."""

import json
import math
import os
import sys

import bpy  # first: the bpy module puts Blender's own modules (addon_utils) on the path

import addon_utils  # noqa: E402


def read(path):
    suffix = os.path.splitext(path)[1].lower()
    if suffix == ".blend":
        bpy.ops.wm.open_mainfile(filepath=path, load_ui=False)
    else:
        bpy.ops.wm.read_homefile(use_empty=True)
        module = {".fbx": "io_scene_fbx", ".glb": "io_scene_gltf2"}[suffix]
        addon_utils.enable(module, default_set=False)
        if suffix == ".fbx":
            bpy.ops.import_scene.fbx(filepath=path)
        else:
            bpy.ops.import_scene.gltf(filepath=path)
    [armature] = [ob for ob in bpy.context.scene.objects if ob.type == 'ARMATURE']
    action = armature.animation_data.action
    first, last = (int(math.floor(f + 0.5)) for f in action.frame_range)
    frames = list(range(first, last + 1))
    joints = {bone.name: [] for bone in armature.pose.bones}
    metres = bpy.context.scene.unit_settings.scale_length
    for frame in frames:
        bpy.context.scene.frame_set(frame)
        for bone in armature.pose.bones:
            joints[bone.name].append(list(metres * (armature.matrix_world @ bone.head)))
    meshes = sorted(ob.name for ob in bpy.context.scene.objects if ob.type == 'MESH'
                    and any(m.type == 'ARMATURE' and m.object == armature for m in ob.modifiers))
    return {"armature": armature.name, "frames": frames, "joints": joints, "meshes": meshes,
            "deform": sorted(b.name for b in armature.data.bones if b.use_deform),
            "actions": sorted(a.name for a in bpy.data.actions)}


if __name__ == "__main__":
    found = read(os.path.abspath(sys.argv[1]))
    with open(sys.argv[2], "w") as out:
        json.dump(found, out)
    sys.stdout.flush()
    os._exit(0)  # past the bpy module's own teardown, unreliable at exit (fullbody_adjust/bpy_exit.py says why)
