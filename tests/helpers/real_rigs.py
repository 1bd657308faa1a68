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
from dataclasses import dataclass, field
from pathlib import Path

import bpy
import numpy as np
from mathutils import Matrix

from tests.helpers.rig_building import (activate, add_body_mesh, add_metarig, import_file, parent_mesh,
                                        rename_bones_unnamed, reparent_bones, round_trip, set_arm_rest,
                                        skinned_meshes, transform_bones, transform_character)

RIGS_DIR = Path(__file__).resolve().parents[1] / "data" / "rigs"
UP = np.array([0.0, 0.0, 1.0])
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


def side_joints(hips, names):
    """joints dict: `names` maps role -> (left bone, right bone) (the character's own left first)."""
    joints = {"hips": hips}
    for role in ROLES:
        left, right = names.get(role, (None, None))
        joints[f"{role}.L"], joints[f"{role}.R"] = left, right
    return joints


def left_right(left, right, roles):
    """{role: (pattern with left spelling, with right spelling)} for {role: bone pattern}."""
    return {role: (p.format(s=left), p.format(s=right)) if p else (None, None) for role, p in roles.items()}


# --- the corpus -------------------------------------------------------------------------------------------------

def _joints(hips, left, right, roles):
    return side_joints(hips, left_right(left, right, roles))


CORPUS = {
    "kenney": dict(file="kenney_characterMedium.fbx", height_m=3.77, rest="T", joints=_joints(
        "Hips", "Left", "Right", {"shoulder": "{s}Arm", "elbow": "{s}ForeArm", "wrist": "{s}Hand", "hip": "{s}UpLeg",
                                  "knee": "{s}Leg", "ankle": "{s}Foot", "ball": "{s}Toes"})),
    # Fingers hang off LowerArm (no wrist bone); Foot.L/R hang off Root (IK-style, not in the leg chain).
    "quaternius_matt": dict(file="quaternius_Characters_Matt.gltf", height_m=1.5, rest="T", joints=_joints(
        "Hips", "L", "R", {"shoulder": "UpperArm.{s}", "elbow": "LowerArm.{s}", "wrist": None, "hip": "UpperLeg.{s}",
                           "knee": "LowerLeg.{s}", "ankle": "Foot.{s}", "ball": None})),
    "quaternius_mannequin_f": dict(file="quaternius_Mannequin_F.glb", height_m=1.81, rest="T", joints=_joints(
        "pelvis", "l", "r", {"shoulder": "upperarm_{s}", "elbow": "lowerarm_{s}", "wrist": "hand_{s}",
                             "hip": "thigh_{s}", "knee": "calf_{s}", "ankle": "foot_{s}", "ball": "ball_{s}"})),
    "kaykit_manny": dict(file="kaykit_manny/manny_med_mod.gltf", height_m=2.21, rest="T", joints=_joints(
        "hips", "l", "r", {"shoulder": "upperarm.{s}", "elbow": "lowerarm.{s}", "wrist": "wrist.{s}",
                           "hip": "upperleg.{s}", "knee": "lowerleg.{s}", "ankle": "foot.{s}", "ball": "toes.{s}"})),
    "godot_plush": dict(file="godot_plush_model.glb", height_m=1.63, rest="A", joints=_joints(
        "DEF-hips", "L", "R", {"shoulder": "DEF-upper_arm.{s}", "elbow": "DEF-forearm.{s}", "wrist": "DEF-hand.{s}",
                               "hip": "DEF-thigh.{s}", "knee": "DEF-shin.{s}", "ankle": "DEF-foot.{s}",
                               "ball": "DEF-toe.{s}"})),
    # The `l-` bones lie on the character's RIGHT (-X, it faces -Y): its own left is `r-`. No hand bones.
    "godot_robot": dict(file="godot_platformer_player.glb", height_m=2.12, rest="A", joints=_joints(
        "hip", "r", "l", {"shoulder": "{s}-arm", "elbow": "{s}-forearm", "wrist": None, "hip": "{s}-thigh",
                          "knee": "{s}-leg", "ankle": "{s}-foot", "ball": None})),
    "gdquest_mannequiny": dict(file="gdquest_mannequiny-0.3.0.glb", height_m=1.8, rest="T", joints=_joints(
        "pelvis", "l", "r", {"shoulder": "upperarm.{s}", "elbow": "lowerarm.{s}", "wrist": "hand.{s}",
                             "hip": "thigh.{s}", "knee": "calf.{s}", "ankle": "foot.{s}", "ball": "ball.{s}"})),
}
CLIP_FILES = {"kenney_run": "kenney_run.fbx",  # animation-only files of the corpus
              "kaykit_moves": "kaykit_Med_MovementBasic.glb"}  # 11 takes: --take picks one
CLIP_CHARACTER = {"kenney_run": "kenney", "kaykit_moves": "kaykit_manny"}  # ... and the corpus character whose
# skeleton (and joints) they share


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


def _load_corpus(name, animation):
    spec = CORPUS[name]
    new = import_file(RIGS_DIR / spec["file"])
    armature = next(ob for ob in new if ob.type == 'ARMATURE')
    if not animation:
        to_rest(armature)
    activate(armature)
    return Rig(name, armature, skinned_meshes(armature), np.array(FACINGS["-Y"]), spec["rest"],
               _metres_per_unit(), dict(spec["joints"]), {"file": spec["file"], "height_m": spec["height_m"]})


def _metres_per_unit():
    return float(bpy.context.scene.unit_settings.scale_length)


# --- the generated variants -------------------------------------------------------------------------------------

METARIG_HEIGHT_M = 1.98  # the basic metarig from its soles (the generated mesh's, at z = 0) to its head's top
METARIG_JOINTS = side_joints("spine", left_right("L", "R", {
    "shoulder": "upper_arm.{s}", "elbow": "forearm.{s}", "wrist": "hand.{s}", "hip": "thigh.{s}", "knee": "shin.{s}",
    "ankle": "foot.{s}", "ball": "toe.{s}"}))

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
    # Matt's IK-style feet hang from Root; Map Bones names the fix (parent each foot to its shin): made here.
    "matt_feet_parented": dict(base="quaternius_matt", reparent={"Foot.L": "LowerLeg.L", "Foot.R": "LowerLeg.R"}),
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
        traits["height_m"] = METARIG_HEIGHT_M - sole
    else:
        base = _load_corpus(spec["base"], animation=False)
        armature, rest, joints = base.armature, base.rest, dict(base.joints)
        traits["height_m"] = base.traits["height_m"]
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
    if "reparent" in spec:
        reparent_bones(armature, spec["reparent"])
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
    activate(armature)
    traits["object_scale"] = float(np.mean(armature.matrix_world.to_scale()))
    return Rig(name, armature, meshes, np.array(FACINGS[facing]), rest, metres_per_unit, joints, traits)


def load(name, animation=False):
    """A corpus character or a generated variant in the current scene (expected empty), as a `Rig`."""
    if name in CORPUS:
        return _load_corpus(name, animation)
    if name in VARIANTS:
        return _build_variant(name)
    raise KeyError(f"no rig {name!r}: corpus {sorted(CORPUS)}, variants {sorted(VARIANTS)}")
