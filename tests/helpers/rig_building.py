"""Building the generated rigs of real_rigs.VARIANTS: the Rigify basic human metarig, its rest arms turned to a T
or an A, a skinned mesh generated around its bones, transforms applied to bones and vertices, bones renamed
"Bone", "Bone.001"..., and round trips through Blender's own glTF and FBX exporters and importers."""

import math
import shutil
import tempfile
from pathlib import Path

import bpy
import numpy as np
from mathutils import Matrix

SIDES = ("L", "R")
UP = np.array([0.0, 0.0, 1.0])

# Bones that get a tube of skin (the others deform nothing: heels, pelvis, breasts).
_SKINNED = ("spine", "spine.001", "spine.002", "spine.003", "spine.004", "spine.005", "spine.006", "shoulder",
            "upper_arm", "forearm", "hand", "thigh", "shin")


def activate(armature):
    """``armature`` the only selected object, and active."""
    for ob in bpy.context.view_layer.objects:
        ob.select_set(False)
    bpy.context.view_layer.objects.active = armature
    armature.select_set(True)


def import_file(path, **options):
    """Import a glTF/GLB or FBX file with Blender's importer (its defaults unless ``options``); returns the new
    objects. The glTF importer's bone display shape (`Icosphere`, collection `glTF_not_exported`) is removed."""
    before = set(bpy.data.objects)
    path = str(path)
    if path.lower().endswith(".fbx"):
        bpy.ops.import_scene.fbx(filepath=path, **options)
    else:
        bpy.ops.import_scene.gltf(filepath=path, **options)
    new = [ob for ob in bpy.data.objects if ob not in before]
    for ob in list(new):
        if ob.type == 'MESH' and ob.parent is None and ob.name.startswith("Icosphere") and not ob.vertex_groups \
                and any(c.name.startswith("glTF_not_exported") for c in ob.users_collection):
            new.remove(ob)
            bpy.data.objects.remove(ob)
    return new


def skinned_meshes(armature):
    """The meshes an Armature modifier binds to ``armature`` (sorted by name)."""
    return sorted((ob for ob in bpy.data.objects if ob.type == 'MESH' and any(
        m.type == 'ARMATURE' and m.object == armature for m in ob.modifiers)), key=lambda ob: ob.name)


def add_metarig():
    """Rigify's basic human metarig (29 bones, faces -Y, arms ~28° down), active and selected."""
    if "rigify" not in bpy.context.preferences.addons:
        bpy.ops.preferences.addon_enable(module="rigify")
    bpy.ops.object.armature_basic_human_metarig_add()
    return bpy.context.active_object


def set_arm_rest(armature, degrees_down):
    """Rotate each arm (upper arm and everything below it) about its shoulder joint in Edit Mode so the upper arm
    points ``degrees_down`` below the horizontal (0: T-pose)."""
    activate(armature)
    bpy.ops.object.mode_set(mode='EDIT')
    bones = armature.data.edit_bones
    for side in SIDES:
        upper = bones[f"upper_arm.{side}"]
        shoulder = np.array(upper.head)
        d = np.array(upper.tail) - shoulder
        horizontal = np.array([d[0], d[1], 0.0])
        now = math.atan2(-d[2], np.linalg.norm(horizontal))
        axis = np.cross(horizontal / np.linalg.norm(horizontal), UP)  # turning about it by +a raises the arm
        turn = Matrix.Rotation(now - math.radians(degrees_down), 4, axis.tolist())
        matrix = Matrix.Translation(shoulder.tolist()) @ turn @ Matrix.Translation((-shoulder).tolist())
        chain = [upper] + list(upper.children_recursive)
        connected = [bone.use_connect for bone in chain]
        for bone in chain[1:]:  # a connected child's head would follow its parent's tail and turn twice
            bone.use_connect = False
        for bone in chain:
            bone.transform(matrix)
        for bone, flag in zip(chain, connected):
            bone.use_connect = flag
    bpy.ops.object.mode_set(mode='OBJECT')


def _prism(p0, p1, section, u, v, rings):
    """Vertices (rings*len(section), 3) and quads of a prism from p0 to p1 whose cross-section is ``section``
    ((k,2) offsets along u, v)."""
    section = np.asarray(section, dtype=np.float64)
    verts = []
    for t in np.linspace(0.0, 1.0, rings):
        centre = p0 + t * (p1 - p0)
        verts.extend(centre + s[0] * u + s[1] * v for s in section)
    k = len(section)
    faces = [(r * k + i, r * k + (i + 1) % k, (r + 1) * k + (i + 1) % k, (r + 1) * k + i)
             for r in range(rings - 1) for i in range(k)]
    return np.array(verts), faces


def _perpendicular(d):
    d = d / np.linalg.norm(d)
    helper = np.array([1.0, 0.0, 0.0]) if abs(d[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = np.cross(d, helper)
    u /= np.linalg.norm(u)
    return u, np.cross(d, u)


def add_body_mesh(armature, sole_z=0.0):
    """A skinned mesh for the metarig at rest (call before any turn or scale): a tube of 8 sides and 6 rings around
    each trunk, arm and leg bone (weight 1 to it), and per foot a block from behind the heel to the ball (bone
    foot) and one from the ball to past the toe tip (bone toe), whose soles lie at ``sole_z`` (the metarig's
    ankle joint is 0.085 m up). Returns the mesh object (unparented, bound by an Armature modifier)."""
    bones = armature.data.bones
    verts, faces, groups = [], [], []

    def add(v, f, group):
        offset = sum(len(x) for x in verts)
        verts.append(v)
        faces.extend(tuple(i + offset for i in face) for face in f)
        groups.append((group, range(offset, offset + len(v))))

    circle = [(math.cos(a), math.sin(a)) for a in np.linspace(0.0, 2 * math.pi, 8, endpoint=False)]
    for bone in bones:
        base = bone.name.split(".")[0] if bone.name.startswith(("shoulder", "upper_arm", "forearm", "hand", "thigh",
                                                                 "shin")) else bone.name
        if base not in _SKINNED:
            continue
        p0, p1 = np.array(bone.head_local), np.array(bone.tail_local)
        radius = float(np.clip(0.2 * np.linalg.norm(p1 - p0), 0.025, 0.12))
        u, v = _perpendicular(p1 - p0)
        add(*_prism(p0, p1, [(radius * c, radius * s) for c, s in circle], u, v, 6), bone.name)
    for side in SIDES:
        ankle, ball = np.array(bones[f"foot.{side}"].head_local), np.array(bones[f"toe.{side}"].head_local)
        toe_tip = np.array(bones[f"toe.{side}"].tail_local)
        heel = np.array([ankle[0], ankle[1] + 0.05, 0.0])
        forward = np.array([0.0, -1.0, 0.0])
        x = np.array([1.0, 0.0, 0.0])
        z = UP
        for group, start, stop, top in ((f"foot.{side}", heel, ball, ankle[2] + 0.02),
                                        (f"toe.{side}", ball, toe_tip + 0.01 * forward, 0.04)):
            p0, p1 = np.array([ankle[0], start[1], 0.0]), np.array([ankle[0], stop[1], 0.0])
            lo, hi = sole_z, top
            section = [(-0.045, lo), (0.0, lo), (0.045, lo), (0.045, 0.5 * (lo + hi)), (0.045, hi), (0.0, hi),
                       (-0.045, hi), (-0.045, 0.5 * (lo + hi))]
            add(*_prism(p0, p1, section, x, z, 5), group)
    mesh = bpy.data.meshes.new("Body")
    mesh.from_pydata(np.concatenate(verts).tolist(), [], faces)
    mesh.update()
    obj = bpy.data.objects.new("Body", mesh)
    bpy.context.scene.collection.objects.link(obj)
    for name, indices in groups:
        group = obj.vertex_groups.get(name) or obj.vertex_groups.new(name=name)
        group.add(list(indices), 1.0, 'REPLACE')
    modifier = obj.modifiers.new("Armature", 'ARMATURE')
    modifier.object = armature
    return obj


def transform_character(armature, mesh, matrix):
    """Apply ``matrix`` to the armature's bones and the mesh's vertices (objects unparented, transforms kept)."""
    transform_bones(armature, matrix)
    if mesh is not None:
        mesh.data.transform(matrix)
    bpy.context.view_layer.update()


def transform_bones(armature, matrix):
    """Apply ``matrix`` to the armature's bones (rest), the pose re-evaluated from them."""
    armature.data.transform(matrix)
    armature.data.update_tag()
    bpy.context.view_layer.update()


def parent_mesh(armature, mesh):
    """Parent the mesh to the armature keeping its world placement (as importers leave skinned meshes)."""
    mesh.parent = armature
    mesh.matrix_parent_inverse = armature.matrix_world.inverted()
    bpy.context.view_layer.update()


def reparent_bones(armature, parents):
    """Each bone of ``parents`` {bone: new parent} given that parent in Edit Mode, not connected (Blender's Keep
    Offset: the bone keeps its rest place), as a user fixes an IK-style foot that hangs from the root."""
    activate(armature)
    bpy.ops.object.mode_set(mode='EDIT')
    bones = armature.data.edit_bones
    for child, parent in parents.items():
        bones[child].use_connect = False
        bones[child].parent = bones[parent]
    bpy.ops.object.mode_set(mode='OBJECT')
    bpy.context.view_layer.update()


def rename_bones_unnamed(armature):
    """Every bone renamed "Bone", "Bone.001", ... in the armature's order; returns {old: new}. Vertex groups of
    the meshes bound to it follow (Blender renames them; any it left are renamed here)."""
    old = [b.name for b in armature.data.bones]
    new = ["Bone"] + [f"Bone.{i:03d}" for i in range(1, len(old))]
    for i, bone in enumerate(armature.data.bones):
        bone.name = f"__tmp{i}"
    for bone, name in zip(armature.data.bones, new):
        bone.name = name
    renamed = dict(zip(old, new))
    for ob in skinned_meshes(armature):
        for group in ob.vertex_groups:
            if group.name in renamed:
                group.name = renamed[group.name]
            elif group.name.startswith("__tmp"):
                group.name = new[int(group.name[5:])]
    return renamed


def round_trip(kind, export_options=None, import_options=None):
    """Export the whole scene with Blender's glTF ('gltf', as GLB) or FBX ('fbx') exporter, start an empty file
    and import it again; returns the imported objects (the glTF bone shape removed)."""
    folder = Path(tempfile.mkdtemp(prefix="fba_rig_"))
    try:
        path = folder / ("rig.glb" if kind == "gltf" else "rig.fbx")
        if kind == "gltf":
            bpy.ops.export_scene.gltf(filepath=str(path), export_format='GLB', **(export_options or {}))
        else:
            bpy.ops.export_scene.fbx(filepath=str(path), **(export_options or {}))
        bpy.ops.wm.read_homefile(use_empty=True)
        return import_file(path, **(import_options or {}))
    finally:
        shutil.rmtree(folder, ignore_errors=True)
