"""Characters as users bring them, loaded into the current (empty) scene: the corpus in tests/data/rigs/ imported
with Blender's glTF and FBX importers at their DEFAULT settings, and generated VARIANTS of the Rigify basic human
metarig (round trips through Blender's own exporters and importers with their option variants, other facings,
A- and T-pose rests, centimetre units, object scales, unnamed joints, soles below the ankle) and of a corpus
character (turned to face +X / +Y).

`load(name)` returns a `Rig`: the armature object, its skinned meshes (the glTF importer's stray `Icosphere` bone
display shape removed) and the traits tests assert against: the world direction the character faces, its own
left, its rest (T or A), the metres per world unit, and `joints`: for each role (`hips`, `shoulder.L`, `elbow.L`,
`wrist.L`, `hip.L`, `knee.L`, `ankle.L`, `ball.L`, the same `.R`) the bone whose HEAD is that joint, or None where
the rig has none; `.L` is the character's OWN left whatever its bones are called. These come from the files
(tests/data/rigs/CREDITS.md) and from how each variant was built, never from the product.

Imported animations are removed and the pose reset to the rest (`animation=False`, the default), so every
character starts from its rest pose with no action; `animation=True` keeps what the importer made.
"""

from __future__ import annotations

import math
import shutil
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import bpy
import numpy as np
from mathutils import Matrix

RIGS_DIR = Path(__file__).resolve().parents[1] / "data" / "rigs"
UP = np.array([0.0, 0.0, 1.0])
SIDES = ("L", "R")
ROLES = ("shoulder", "elbow", "wrist", "hip", "knee", "ankle", "ball")
FACINGS = {"-Y": (0.0, -1.0, 0.0), "+Y": (0.0, 1.0, 0.0), "+X": (1.0, 0.0, 0.0), "-X": (-1.0, 0.0, 0.0)}
TURN_FROM_MINUS_Y = {"-Y": 0.0, "+X": 90.0, "+Y": 180.0, "-X": -90.0}  # degrees about +Z


@dataclass
class Rig:
    name: str
    armature: bpy.types.Object
    meshes: list
    facing: np.ndarray  # world, horizontal unit vector: where face and toes point
    rest: str  # "T" or "A" (upper arms within ~10° of horizontal, or 30-45° down)
    metres_per_unit: float  # of the scene's world units
    joints: dict  # role -> bone whose head is that joint (None: the rig has no such joint)
    traits: dict = field(default_factory=dict)  # anything else a variant is known for

    @property
    def left(self):
        """World unit vector to the character's own left."""
        return np.cross(UP, self.facing)

    def bone(self, role):
        return self.joints.get(role)


def _side_joints(hips, names):
    """joints dict: `names` maps role -> (left bone, right bone) (the character's own left first)."""
    joints = {"hips": hips}
    for role in ROLES:
        left, right = names.get(role, (None, None))
        joints[f"{role}.L"], joints[f"{role}.R"] = left, right
    return joints


def _lr(left, right, roles):
    """{role: (pattern with left spelling, with right spelling)} for {role: bone pattern}."""
    return {role: (p.format(s=left), p.format(s=right)) if p else (None, None) for role, p in roles.items()}


# --- the corpus -------------------------------------------------------------------------------------------------

CORPUS = {
    "kenney": dict(file="kenney_characterMedium.fbx", rest="T", joints=_side_joints("Hips", _lr(
        "Left", "Right", {"shoulder": "{s}Arm", "elbow": "{s}ForeArm", "wrist": "{s}Hand", "hip": "{s}UpLeg",
                                "knee": "{s}Leg", "ankle": "{s}Foot", "ball": "{s}Toes"}))),
    # Fingers hang off LowerArm (no wrist bone); Foot.L/R hang off Root (IK-style, not in the leg chain).
    "quaternius_matt": dict(file="quaternius_Characters_Matt.gltf", rest="T", joints=_side_joints("Hips", _lr(
        "L", "R", {"shoulder": "UpperArm.{s}", "elbow": "LowerArm.{s}", "wrist": None, "hip": "UpperLeg.{s}",
                         "knee": "LowerLeg.{s}", "ankle": "Foot.{s}", "ball": None}))),
    "quaternius_mannequin_f": dict(file="quaternius_Mannequin_F.glb", rest="T", joints=_side_joints("pelvis", _lr(
        "l", "r", {"shoulder": "upperarm_{s}", "elbow": "lowerarm_{s}", "wrist": "hand_{s}", "hip": "thigh_{s}",
                         "knee": "calf_{s}", "ankle": "foot_{s}", "ball": "ball_{s}"}))),
    "kaykit_manny": dict(file="kaykit_manny/manny_med_mod.gltf", rest="T", joints=_side_joints("hips", _lr(
        "l", "r", {"shoulder": "upperarm.{s}", "elbow": "lowerarm.{s}", "wrist": "wrist.{s}",
                         "hip": "upperleg.{s}", "knee": "lowerleg.{s}", "ankle": "foot.{s}", "ball": "toes.{s}"}))),
    "godot_plush": dict(file="godot_plush_model.glb", rest="A", joints=_side_joints("DEF-hips", _lr(
        "L", "R", {"shoulder": "DEF-upper_arm.{s}", "elbow": "DEF-forearm.{s}", "wrist": "DEF-hand.{s}",
                         "hip": "DEF-thigh.{s}", "knee": "DEF-shin.{s}", "ankle": "DEF-foot.{s}",
                         "ball": "DEF-toe.{s}"}))),
    # The `l-` bones lie on the character's RIGHT (-X, it faces -Y): its own left is `r-`. No hand bones.
    "godot_robot": dict(file="godot_platformer_player.glb", rest="A", joints=_side_joints("hip", _lr(
        "r", "l", {"shoulder": "{s}-arm", "elbow": "{s}-forearm", "wrist": None, "hip": "{s}-thigh",
                         "knee": "{s}-leg", "ankle": "{s}-foot", "ball": None}))),
    "gdquest_mannequiny": dict(file="gdquest_mannequiny-0.3.0.glb", rest="T", joints=_side_joints("pelvis", _lr(
        "l", "r", {"shoulder": "upperarm.{s}", "elbow": "lowerarm.{s}", "wrist": "hand.{s}", "hip": "thigh.{s}",
                         "knee": "calf.{s}", "ankle": "foot.{s}", "ball": "ball.{s}"}))),
}
CLIP_FILES = {"kenney_run": "kenney_run.fbx"}


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


def to_rest(armature):
    """No animation on the armature, every pose bone at its rest (identity channels)."""
    armature.animation_data_clear()
    for pb in armature.pose.bones:
        pb.location = (0.0, 0.0, 0.0)
        pb.rotation_quaternion = (1.0, 0.0, 0.0, 0.0)
        pb.rotation_euler = (0.0, 0.0, 0.0)
        pb.rotation_axis_angle = (0.0, 0.0, 1.0, 0.0)
        pb.scale = (1.0, 1.0, 1.0)
    bpy.context.view_layer.update()


def _activate(armature):
    for ob in bpy.context.view_layer.objects:
        ob.select_set(False)
    bpy.context.view_layer.objects.active = armature
    armature.select_set(True)


def _load_corpus(name, animation):
    spec = CORPUS[name]
    new = import_file(RIGS_DIR / spec["file"])
    armature = next(ob for ob in new if ob.type == 'ARMATURE')
    if not animation:
        to_rest(armature)
    _activate(armature)
    return Rig(name, armature, skinned_meshes(armature), np.array(FACINGS["-Y"]), spec["rest"],
               _metres_per_unit(), dict(spec["joints"]), {"file": spec["file"]})


def _metres_per_unit():
    return float(bpy.context.scene.unit_settings.scale_length)


# --- the generated variants -------------------------------------------------------------------------------------

METARIG_JOINTS = _side_joints("spine", _lr("L", "R", {
    "shoulder": "upper_arm.{s}", "elbow": "forearm.{s}", "wrist": "hand.{s}", "hip": "thigh.{s}", "knee": "shin.{s}",
    "ankle": "foot.{s}", "ball": "toe.{s}"}))
# Bones that get a tube of skin (the others deform nothing: heels, pelvis, breasts).
_SKINNED = ("spine", "spine.001", "spine.002", "spine.003", "spine.004", "spine.005", "spine.006", "shoulder",
            "upper_arm", "forearm", "hand", "thigh", "shin")
_SOLE_GAP = 0.0  # the default mesh's soles rest on z = 0, the metarig's ankle is 0.085 m above


def add_metarig():
    """Rigify's basic human metarig (29 bones, faces -Y, arms ~28° down), active and selected."""
    if "rigify" not in bpy.context.preferences.addons:
        bpy.ops.preferences.addon_enable(module="rigify")
    bpy.ops.object.armature_basic_human_metarig_add()
    return bpy.context.active_object


def set_arm_rest(armature, degrees_down):
    """Rotate each arm (upper arm and everything below it) about its shoulder joint in Edit Mode so the upper arm
    points ``degrees_down`` below the horizontal (0: T-pose)."""
    _activate(armature)
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


# Each variant: how it is built, and what it is known to be. "base": 'metarig' (the basic human metarig with a
# generated skinned mesh) or a corpus name; the steps in the order they are applied.
VARIANTS = {
    "metarig": dict(base="metarig"),
    "metarig_tpose": dict(base="metarig", arms_down=0.0, rest="T"),
    "metarig_apose": dict(base="metarig", arms_down=40.0, rest="A"),
    "metarig_face_px": dict(base="metarig", facing="+X"),
    "metarig_face_nx": dict(base="metarig", facing="-X"),
    "metarig_face_py": dict(base="metarig", facing="+Y"),
    "metarig_low_soles": dict(base="metarig", sole_below=0.06),
    "metarig_cm_units": dict(base="metarig", units_cm=True),
    "metarig_object_scale_0.01": dict(base="metarig", data_scale=100.0, object_scale=0.01),
    "metarig_object_scale_100": dict(base="metarig", data_scale=0.01, object_scale=100.0),
    "metarig_unnamed": dict(base="metarig", unnamed=True),
    "metarig_gltf_blender": dict(base="metarig", trip=("gltf", {}, {"bone_heuristic": 'BLENDER'})),
    "metarig_gltf_temperance": dict(base="metarig", trip=("gltf", {}, {"bone_heuristic": 'TEMPERANCE'})),
    "metarig_gltf_fortune": dict(base="metarig", trip=("gltf", {}, {"bone_heuristic": 'FORTUNE'})),
    "metarig_fbx": dict(base="metarig", trip=("fbx", {}, {})),
    "metarig_fbx_auto_orient": dict(base="metarig", trip=("fbx", {}, {"automatic_bone_orientation": True})),
    "metarig_fbx_no_leaf": dict(base="metarig", trip=("fbx", {"add_leaf_bones": False}, {})),
    "metarig_fbx_auto_orient_no_leaf": dict(base="metarig", trip=(
        "fbx", {"add_leaf_bones": False}, {"automatic_bone_orientation": True})),
    "metarig_gltf_unnamed_face_px": dict(base="metarig", unnamed=True, facing="+X",
                                         trip=("gltf", {}, {"bone_heuristic": 'BLENDER'})),
    "mannequin_f_face_px": dict(base="quaternius_mannequin_f", facing="+X"),
    "mannequin_f_face_py": dict(base="quaternius_mannequin_f", facing="+Y"),
}
ALL = tuple(CORPUS) + tuple(VARIANTS)


def _build_variant(name):
    spec = VARIANTS[name]
    facing = spec.get("facing", "-Y")
    traits = {"built_from": spec["base"]}
    if spec["base"] == "metarig":
        armature = add_metarig()
        if "arms_down" in spec:
            set_arm_rest(armature, spec["arms_down"])
        sole = -spec.get("sole_below", 0.0)
        mesh = add_body_mesh(armature, sole_z=sole)
        if sole:  # everything up so the soles rest on the floor again: the ankle 0.085 + 0.06 m above them
            transform_character(armature, mesh, Matrix.Translation((0.0, 0.0, -sole)))
            traits["sole_below_ankle_m"] = 0.085 - sole
        rest = spec.get("rest", "A")  # the metarig's arms are 28° down
        joints = dict(METARIG_JOINTS)
    else:
        base = _load_corpus(spec["base"], animation=False)
        armature, rest, joints = base.armature, base.rest, dict(base.joints)
        mesh = None
        for ob in base.meshes:  # bake each mesh's placement into its data so a turn of the data turns all
            ob.parent = None
            ob.data.transform(ob.matrix_world)
            ob.matrix_world = Matrix.Identity(4)
        transform_bones(armature, armature.matrix_world.copy())
        armature.matrix_world = Matrix.Identity(4)
        meshes = base.meshes
    turn = Matrix.Rotation(math.radians(TURN_FROM_MINUS_Y[facing]), 4, 'Z')
    if spec["base"] == "metarig":
        transform_character(armature, mesh, turn)
        meshes = [mesh]
    else:
        transform_bones(armature, turn)
        for ob in meshes:
            ob.data.transform(turn)
    metres_per_unit = 1.0
    if spec.get("units_cm"):
        transform_character(armature, mesh, Matrix.Scale(100.0, 4))
        bpy.context.scene.unit_settings.scale_length = 0.01
        bpy.context.scene.unit_settings.length_unit = 'CENTIMETERS'
        metres_per_unit = 0.01
    if "data_scale" in spec:
        transform_bones(armature, Matrix.Scale(spec["data_scale"], 4))
        armature.scale = (spec["object_scale"],) * 3
        bpy.context.view_layer.update()
    for ob in meshes:
        parent_mesh(armature, ob)
    if spec.get("unnamed"):
        renamed = rename_bones_unnamed(armature)
        joints = {role: renamed.get(bone) if bone else None for role, bone in joints.items()}
    if "trip" in spec:
        kind, export_options, import_options = spec["trip"]
        traits["round_trip"] = {"format": kind, "export": export_options, "import": import_options}
        new = round_trip(kind, export_options, import_options)
        armature = next(ob for ob in new if ob.type == 'ARMATURE')
        meshes = skinned_meshes(armature)
        to_rest(armature)
        metres_per_unit = _metres_per_unit()
    bpy.context.view_layer.update()
    _activate(armature)
    traits["object_scale"] = float(np.mean(armature.matrix_world.to_scale()))
    return Rig(name, armature, meshes, np.array(FACINGS[facing]), rest, metres_per_unit, joints, traits)


def load(name, animation=False):
    """A corpus character or a generated variant in the current scene (expected empty), as a `Rig`."""
    if name in CORPUS:
        return _load_corpus(name, animation)
    if name in VARIANTS:
        return _build_variant(name)
    raise KeyError(f"no rig {name!r}: corpus {sorted(CORPUS)}, variants {sorted(VARIANTS)}")
