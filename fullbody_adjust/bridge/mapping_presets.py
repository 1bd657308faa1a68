"""Bone-name presets for the five-group body model (solver/vocabulary.py's groups).

Pure data, no bpy. A preset names, per group, the chain's slots in parent → child order. A slot is a string:

- ``"spine.001"``: one bone name;
- ``"abdomenLower|abdomen"``: alternatives, the first one the rig has is taken;
- ``"?shoulder.{side}"``: optional (a leading ``?``), e.g. clavicles, extra spine and neck bones;
- ``{side}`` is replaced by the preset's left/right spelling; groups ``arm``, ``hand``, ``leg`` and ``foot``
  are sided (they become ``arm.L`` and ``arm.R``...), the others are not.

Names are compared case-insensitively (Daz spells both ``lForeArm`` and ``lForearmBend``). Each preset lists
variants: a label and a prefix pattern (a regular expression) that every bone name of that variant starts
with, e.g. Mixamo's ``mixamorig:`` (also ``mixamorig1:``, ``mixamorig_``), Rigify's ``DEF-``. The variants of
a preset are tried in order; see ``mapping.map_rig`` for how a match is accepted.
"""

from dataclasses import dataclass

SIDED_GROUPS = ("arm", "hand", "leg", "foot")


@dataclass(frozen=True)
class Preset:
    name: str
    sides: tuple  # (left spelling, right spelling) substituted for {side}
    table: dict  # group ("root", "trunk", "arm", ...) -> tuple of slot strings
    variants: tuple  # ((label, prefix regex), ...), tried in order


RIGIFY = Preset(
    name="Rigify",
    sides=("L", "R"),
    table={
        "root": ("spine",),
        "trunk": ("spine.001", "spine.002", "spine.003"),
        "arm": ("?shoulder.{side}", "upper_arm.{side}", "forearm.{side}"),
        "hand": ("hand.{side}",),
        "leg": ("thigh.{side}", "shin.{side}"),
        "foot": ("foot.{side}",),
        "head": ("spine.004", "?spine.005", "spine.006"),
    },
    # A generated rig keeps the metarig's names behind DEF- (deforming) and ORG- (original) prefixes; its
    # plain-named bones are controls (hand_ik.L...), so the prefixed variants come first.
    variants=(
        ("Rigify generated rig (DEF- bones)", "DEF-"),
        ("Rigify generated rig (ORG- bones)", "ORG-"),
        ("Rigify metarig", ""),
    ),
)

UNREAL = Preset(
    name="Unreal mannequin",
    sides=("l", "r"),
    table={
        "root": ("pelvis",),
        # UE4 has spine_01..03, UE5 spine_01..05. Twist bones (upperarm_twist_01_l...) are not chain bones.
        "trunk": ("spine_01", "spine_02", "?spine_03", "?spine_04", "?spine_05"),
        "arm": ("?clavicle_{side}", "upperarm_{side}", "lowerarm_{side}"),
        "hand": ("hand_{side}",),
        "leg": ("thigh_{side}", "calf_{side}"),
        "foot": ("foot_{side}",),
        "head": ("neck_01", "?neck_02", "head"),
    },
    variants=(("Unreal mannequin", ""),),
)

DAZ = Preset(
    name="Daz",
    sides=("l", "r"),
    table={
        "root": ("hip",),
        # Genesis 3/8 (abdomenLower...chestUpper), Genesis 2 (abdomen, abdomen2, chest), the Daz BVH (abdomen, chest).
        "trunk": ("abdomenLower|abdomen", "?abdomenUpper|abdomen2", "chestLower|chest", "?chestUpper"),
        # The ...Bend bones of Genesis 3/8 carry the joint; their ...Twist children are skipped.
        "arm": ("?{side}Collar", "{side}ShldrBend|{side}Shldr", "{side}ForearmBend|{side}ForeArm"),
        "hand": ("{side}Hand",),
        "leg": ("{side}ThighBend|{side}Thigh", "{side}Shin"),
        "foot": ("{side}Foot",),
        "head": ("neckLower|neck", "?neckUpper", "head"),
    },
    variants=(("Daz", ""),),
)

MOTIONBUILDER = Preset(
    name="MotionBuilder",
    sides=("Left", "Right"),
    table={
        "root": ("Hips",),
        # CMU: LowerBack, Spine, Spine1. Mixamo: Spine, Spine1, Spine2. HumanIK allows Spine..Spine9.
        "trunk": ("?LowerBack", "Spine", "?Spine1", "?Spine2", "?Spine3"),
        "arm": ("?{side}Shoulder", "{side}Arm", "{side}ForeArm"),
        "hand": ("{side}Hand",),
        "leg": ("{side}UpLeg", "{side}Leg"),
        "foot": ("{side}Foot",),
        "head": ("Neck", "?Neck1", "?Neck2", "Head"),
    },
    variants=(
        ("Mixamo", r"mixamorig\d*[:_]"),
        ("MotionBuilder/CMU", ""),
        ("MotionBuilder/CMU with a namespace", r"[^:]+:"),
    ),
)

PRESETS = (RIGIFY, UNREAL, DAZ, MOTIONBUILDER)
