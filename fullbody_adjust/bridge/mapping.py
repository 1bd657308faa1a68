"""Bone mapping: which rig bones form each group of the five-group body model — the one entry point.

``map_rig(desc)`` maps a rig given as plain data (``rig_description.RigDescription``: bone names, parents, rest
heads and tails; no bpy): the name presets first (``preset_matching`` over ``mapping_presets``), then detection
from the shape of the hierarchy (``mapping_detection``); the result is a ``bone_map.BoneMap``, or a one-line
``MappingError`` naming what is missing. The Blender side (functions taking bpy objects, at the end; this module
never imports bpy): ``describe_armature``, ``store_map``, ``load_map``, ``read_map``, ``ensure_map``; the map is
stored on the armature object as ``obj.fullbody_adjust.bone_map`` (items with string ``group`` and ``bone``, a
group's items in chain order). A map the user typed or edited there is used as it is, checked, never replaced
by detection (``read_map``).

Conventions. Positions are compared in the rig's world orientation (``RigDescription.orientation``, the
object's rotation: an FBX import keeps Y-up bones under a rotated object): z is up. Joints are bone heads, never
tails (``rig_description``). The .L groups are the limbs on the character's own left, from where its skeleton
faces (``body_sides``: feet and knees, whatever the object's axes), side markers in names deciding when the
skeleton does not say clearly (``rig_description.side_of_name``).

Arms without a hand bone (a robot's forearm ending in a fist, fingers fanning straight out of the forearm as on
Quaternius' characters): the arm is mapped and its hand group left empty; the wrist, the hand's effector, is then
where the arm's last bone ends as a joint (solver.joint_ends), whatever hangs there rides on the forearm, and the
map's source says so ("no hand bones: the left wrist is the end of ..."). Stored, such a hand is a row with no
bone; a hand row emptied by the user means the same.

Rigify: a generated rig (``control_rig``) is described in its metarig's hierarchy and mapped to its ORG- bones,
which the solve moves and its controls follow. A rig with only DEF- bones (a game export) maps to those:

* DEF- limbs are split in two, ``DEF-upper_arm.L`` + ``DEF-upper_arm.L.001`` (a child continuing it). The
  first segment is the chain bone: the next chain joint (head of ``DEF-forearm.L``) lies on its line, so the
  chain joints are the real shoulder, elbow and wrist, and the ``.001`` child follows it. This is checked for
  every chain bone that has such a ``<name>.001`` child (``BoneMap.problems``).
* ``DEF-shoulder.L`` hangs from ``ORG-shoulder.L``, not above ``DEF-upper_arm.L``, so it cannot lead that
  chain: an optional slot (clavicles, extra spine and neck bones) whose bone breaks the chain's ancestor
  order is left out, and the arm is [DEF-upper_arm, DEF-forearm] (arms without a clavicle are allowed).
"""


import numpy as np

from ..solver.vocabulary import GROUPS, REQUIRED_GROUPS
from . import body_sides
from .body_sides import Limb
from .bone_map import GROUP_LABELS, BoneMap, MappingError
from .mapping_detection import REPORT_ORDER, STAGE, NotFound, detect, detect_map, missing_message
from .pose import parent_indices
from .preset_matching import preset_maps
from .rig_description import RigDescription, side_of_name

# What callers import from here: the map, its errors and labels, the rig as data and the two ways of mapping.
__all__ = ["GROUP_LABELS", "BoneMap", "MappingError", "RigDescription", "describe_armature", "detect_map",
           "ensure_map", "is_typed", "load_map", "map_rig", "preset_maps", "read_map", "side_of_name", "store_map"]

# --- the whole mapping ------------------------------------------------------------------------------------

def map_rig(desc):
    """The rig's BoneMap: the first preset variant that maps every required group and fits the rig, else
    detection from the hierarchy. MappingError (one line) names what is missing."""
    if not len(desc):
        raise MappingError(f"Cannot map rig '{desc.name}': it has no bones")
    attempts = preset_maps(desc)
    for label, bone_map, problems in attempts:
        if not problems:
            return with_body_sides(desc, bone_map)
    try:
        return detect(desc)
    except NotFound as failure:
        detected = failure
    # Report what a preset nearly found when it got at least half the groups, unless detection got further
    # through the body (REPORT_ORDER stages: a missing root or trunk comes before a missing foot or hand),
    # else detection's failure, which names the bone where it stopped.
    # A preset's hands count as missing when it did not find them (only detection maps arms without hands).
    def unmatched(bone_map):
        return [g for g in REQUIRED_GROUPS if not bone_map.bones(g)]

    nearest = max(attempts, key=lambda a: len(REQUIRED_GROUPS) - len(unmatched(a[1])), default=None)
    if nearest is not None and len(REQUIRED_GROUPS) - len(unmatched(nearest[1])) >= len(REQUIRED_GROUPS) / 2:
        label, bone_map, problems = nearest
        missing = unmatched(bone_map)
        group = min(missing, key=REPORT_ORDER.index) if missing else None
        if group is None or STAGE[group] >= STAGE[detected.group]:
            if group:
                raise MappingError(missing_message(desc, group, matched=f"other bones have {label} names"))
            raise MappingError(f"Cannot map rig '{desc.name}': it has {label} names but {problems[0]}")
    raise MappingError(missing_message(desc, detected.group, detected.detail, line=detected.line))


def with_body_sides(desc, bone_map):
    """``bone_map`` with its .L and .R groups swapped when the skeleton clearly faces the other way than its
    side names say (``body_sides``: mirrored labels, as on the Godot platformer robot); else itself."""
    sk = desc._skeleton
    idx = {g: [desc.index(b) for b in bones] for g, bones in bone_map.groups.items()}
    legs = [Limb(tuple(idx[f"leg.{s}"]), idx[f"foot.{s}"][0]) for s in "LR"]
    arms = [Limb(tuple(idx[f"arm.{s}"]), idx.get(f"hand.{s}", [None])[0]) for s in "LR"]
    lat = body_sides.lateral(sk, *legs)
    if lat is None:
        return bone_map
    # Only a map whose left arm is on its left leg's side can be mirrored as a whole.
    wrists = [body_sides.end_point(sk, arm) for arm in arms]
    if float((wrists[0] - wrists[1]) @ lat) <= 0:
        return bone_map
    if body_sides.left_pair(sk, legs, arms).left == 0:
        return bone_map
    swap = {"L": "R", "R": "L"}
    groups = {(g[:-1] + swap[g[-1]] if g[-2:] in (".L", ".R") else g): bones for g, bones in bone_map.groups.items()}
    return BoneMap(groups, source=f"{bone_map.source}, sides from the skeleton's facing")


# --- Blender ------------------------------------------------------------------------------------------------
# These take bpy objects; nothing here imports bpy.

def describe_armature(obj):
    """RigDescription of an armature object's rest bones (armature space) and its world orientation."""
    if obj is None or getattr(obj, "type", None) != 'ARMATURE':
        raise MappingError(f"Cannot map '{getattr(obj, 'name', obj)}': it is not an armature")
    bones = obj.data.bones
    n = len(bones)
    names = tuple(b.name for b in bones)
    parents = parent_indices(bones)
    if _is_control_rig(obj):
        parents = _control_rig().skeleton_parents(names, parents)
    heads = np.empty(n * 3, dtype=np.float32)
    tails = np.empty(n * 3, dtype=np.float32)
    bones.foreach_get("head_local", heads)
    bones.foreach_get("tail_local", tails)
    rotation = np.array(obj.matrix_world.to_3x3().normalized(), dtype=np.float64)
    return RigDescription(names=names, parents=parents, heads=heads.reshape(n, 3), tails=tails.reshape(n, 3),
                          name=obj.name, orientation=rotation)


_MADE = "mapped_automatically"  # ID property on obj.fullbody_adjust: the items of the last map mapping stored


def store_map(obj, bone_map, typed=False):
    """Write ``bone_map`` to ``obj.fullbody_adjust.bone_map`` (replacing what was there). Unless ``typed``, it
    is recorded as made by mapping, so that ``read_map`` may map afresh when it stops fitting, as long as
    nobody edits it."""
    settings = obj.fullbody_adjust
    items = settings.bone_map
    items.clear()
    handless = bone_map.handless()  # shown as a hand row with no bone: the wrist is the arm's end
    rows = [(g, b) for g in GROUPS for b in (bone_map.bones(g) or (("",) if g in handless else ()))]
    for group, bone in rows + [(g, b) for g, b in bone_map.items() if g not in GROUPS]:
        item = items.add()
        item.group = group
        item.bone = bone
    if typed:
        settings.pop(_MADE, None)
    else:
        settings[_MADE] = _as_text(bone_map.items())


def _as_text(items):
    return "\n".join(f"{group}\t{bone}" for group, bone in items)


def load_map(obj):
    """The map stored on ``obj`` (items with an empty bone name are skipped: a hand without a bone is an arm that
    ends at its last bone, ``BoneMap.handless``), or None when nothing is stored."""
    pairs = [(item.group, item.bone) for item in obj.fullbody_adjust.bone_map if item.bone]
    return BoneMap.from_items(pairs, source="stored") if pairs else None


def is_typed(obj):
    """The stored map is the user's: typed or edited in the Bone Mapping sub-panel since mapping stored it."""
    stored = load_map(obj)
    return stored is not None and obj.fullbody_adjust.get(_MADE) != _as_text(stored.items())


def read_map(obj):
    """The map a solve or a retarget uses on ``obj``, storing nothing: the stored map when it fits; else the
    rig mapped afresh (``map_rig``; a generated Rigify rig on its ORG- bones), unless the stored map is the
    user's.

    A map the user typed or edited in the Bone Mapping sub-panel (``is_typed``) is used as it is, never
    replaced by detection: when it does not fit the rig, MappingError names its first problem, the bone and
    why, in one line, and Map Again (``map_rig`` + ``store_map``) starts over. A map mapping stored itself and
    nobody edited is mapped again when the rig changed under it (a bone renamed or removed)."""
    desc = describe_armature(obj)
    stored = load_map(obj)
    if stored is not None:
        problems = stored.problems(desc)
        if not problems and _is_control_rig(obj):
            problems = [f"{group}: '{bone}' is not an ORG- bone (a generated Rigify rig is solved on its ORG- "
                        f"bones)" for group, bone in stored.items() if not bone.startswith(_control_rig().ORG)]
        if not problems:
            return stored
        if is_typed(obj):
            more = f" (and {len(problems) - 1} more)" if len(problems) > 1 else ""
            raise MappingError(f"The bone map typed on '{obj.name}' does not fit it: {problems[0]}{more}; fix it "
                               f"in Bone Mapping or press Map Again")
    return _map_control_rig(desc) if _is_control_rig(obj) else map_rig(desc)


def ensure_map(obj):
    """``read_map(obj)``, stored on ``obj`` when it is not the stored map. MappingError (one line) when the
    user's map does not fit or the rig cannot be mapped; the stored items are then left as they were."""
    bone_map = read_map(obj)
    if bone_map.source != "stored":
        store_map(obj, bone_map)
    return bone_map


def _control_rig():
    from . import control_rig  # imports Blender's modules: only the Blender-side functions need it
    return control_rig


def _is_control_rig(obj):
    return _control_rig().is_generated_rigify(obj)


def _all_org(bone_map):
    return all(bone.startswith(_control_rig().ORG) for _group, bone in bone_map.items())


def _map_control_rig(desc):
    """The ORG- variant of the Rigify preset on a generated rig's skeleton, else the usual mapping."""
    for _label, bone_map, problems in preset_maps(desc):
        if not problems and _all_org(bone_map):
            return bone_map
    return map_rig(desc)
