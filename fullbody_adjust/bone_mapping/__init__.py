"""Bone mapping without Blender: which bones of a rig, given as plain data, form each group of the five-group body
model. Imports no bpy (tests/test_mapping_no_bpy.py proves it); bridge/rig/mapping.py reads an armature into a
RigDescription and keeps the map on it.

Modules, each importing only those listed before it (and solver/ for the group names and joint ends):
``rig_description`` (the rig as data: names, parents, rest heads and tails, hierarchy questions, side markers in
names), ``bone_map`` (the map, its fit to a rig, MappingError), ``body_sides`` (which limbs are on the character's
left, from its skeleton), ``presets`` + ``presets.toml`` (name presets) and ``preset_matching`` (trying them),
``limbs`` (splitting a found limb into its groups' bones), ``detection`` (mapping from the hierarchy's shape),
``mapping`` (``map_rig``: presets first, then detection)."""

from .bone_map import GROUP_LABELS, BoneMap, MappingError
from .detection import detect_map
from .mapping import map_rig
from .preset_matching import preset_maps
from .rig_description import RigDescription, side_of_name

__all__ = ["GROUP_LABELS", "BoneMap", "MappingError", "RigDescription", "detect_map", "map_rig", "preset_maps",
           "side_of_name"]
