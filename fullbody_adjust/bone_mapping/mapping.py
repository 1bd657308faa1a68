"""Bone mapping: which rig bones form each group of the five-group body model — the one entry point.

``map_rig(desc)`` maps a rig given as plain data (``rig_description.RigDescription``: bone names, parents, rest
heads and tails; no bpy): the name presets first (``preset_matching`` over ``presets``), then detection
from the shape of the hierarchy (``detection``); the result is a ``bone_map.BoneMap``, or a one-line
``MappingError`` naming what is missing. The Blender side (reading an armature's bones into a RigDescription,
storing and loading the map on the armature object) is bridge/rig/mapping.py.

Conventions. Positions are compared in the rig's world orientation (``RigDescription.orientation``, the
object's rotation: an FBX import keeps Y-up bones under a rotated object): z is up. Joints are bone heads, never
tails (``rig_description``). The .L groups are the limbs on the character's own left, from where its skeleton
faces (``body_sides``: feet and knees, whatever the object's axes), side markers in names deciding when the
skeleton does not say clearly (``rig_description.side_of_name``).

Arms without a hand bone (a robot's forearm ending in a fist, fingers fanning straight out of the forearm as on
Quaternius' characters): the arm is mapped and its hand group left empty; the wrist, the hand's effector, is then
where the arm's last bone ends as a joint (solver.joint_ends), whatever hangs there rides on the forearm, and the
map's source says so ("no hand bones: the left wrist is the end of ..."). Stored, such a hand is a row with no
bone (bridge/rig/mapping.py); a hand row emptied by the user means the same.

Rigify: a generated rig (bridge/rig/control_rig.py) is described in its metarig's hierarchy and mapped to its ORG- bones,
which the solve moves and its controls follow. A rig with only DEF- bones (a game export) maps to those:

* DEF- limbs are split in two, ``DEF-upper_arm.L`` + ``DEF-upper_arm.L.001`` (a child continuing it). The
  first segment is the chain bone: the next chain joint (head of ``DEF-forearm.L``) lies on its line, so the
  chain joints are the real shoulder, elbow and wrist, and the ``.001`` child follows it. This is checked for
  every chain bone that has such a ``<name>.001`` child (``BoneMap.problems``).
* ``DEF-shoulder.L`` hangs from ``ORG-shoulder.L``, not above ``DEF-upper_arm.L``, so it cannot lead that
  chain: an optional slot (clavicles, extra spine and neck bones) whose bone breaks the chain's ancestor
  order is left out, and the arm is [DEF-upper_arm, DEF-forearm] (arms without a clavicle are allowed).
"""

from ..solver.vocabulary import REQUIRED_GROUPS
from . import body_sides
from .body_sides import Limb
from .bone_map import BoneMap, MappingError
from .detection import REPORT_ORDER, STAGE, NotFound, detect, missing_message
from .preset_matching import preset_maps

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
    if body_sides.left_pair(sk, legs, arms) == 0:
        return bone_map
    swap = {"L": "R", "R": "L"}
    groups = {(g[:-1] + swap[g[-1]] if g[-2:] in (".L", ".R") else g): bones for g, bones in bone_map.groups.items()}
    return BoneMap(groups, source=f"{bone_map.source}, sides from the skeleton's facing")
