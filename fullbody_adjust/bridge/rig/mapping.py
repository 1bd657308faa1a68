"""The bone map on a Blender armature: ``describe_armature`` reads its rest bones into a RigDescription for
bone_mapping.map_rig; ``store_map``, ``load_map``, ``read_map``, ``ensure_map`` keep the map on the armature object
as ``obj.fullbody_adjust.bone_map`` (items with string ``group`` and ``bone``, a group's items in chain order). A
map the user typed or edited there is used as it is, checked, never replaced by detection (``read_map``). These
functions take bpy objects; this module imports no bpy itself. A generated Rigify rig (``control_rig``) is
described in its metarig's hierarchy and mapped to its ORG- bones.

The mapping itself (presets, detection, sides, the BoneMap type) needs no Blender: fullbody_adjust/bone_mapping.
"""

import numpy as np

from ...bone_mapping import GROUP_LABELS, BoneMap, MappingError, RigDescription, map_rig, preset_maps
from ...solver.vocabulary import GROUPS
from ..reading.pose import parent_indices

# What callers import from here: the Blender side, and the map, its errors and labels and map_rig they use with it.
__all__ = ["GROUP_LABELS", "BoneMap", "MappingError", "describe_armature", "ensure_map", "is_typed", "load_map",
           "map_rig", "read_map", "store_map"]

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
