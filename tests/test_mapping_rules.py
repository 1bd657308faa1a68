"""Bone mapping onto the five-group body model (fullbody_adjust/bone_mapping), without Blender.

Rigs are built by hand as RigDescriptions: synthetic Mixamo, Unreal (UE4/UE5) and Daz Genesis 8 skeletons with
their real bone names and plausible rest positions (metres, z up, facing -Y, left at +X, as in Blender), and the
CMU and Daz BVH skeletons of the shared clips read with tests/helpers/bvh.py (file axes: Y up, so they also
exercise RigDescription.orientation). The Rigify metarigs, a generated Rigify rig and the imported BVH clips are
mapped through Blender in tests/blender/test_mapping.py, which reuses the rig builders below.
"""

import re

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fullbody_adjust.bone_mapping import (
    BoneMap,
    MappingError,
    RigDescription,
    detect_map,
    map_rig,
    preset_maps,
    side_of_name,
)
from fullbody_adjust.solver.vocabulary import GROUPS, REQUIRED_GROUPS
from tests.helpers.bvh import CMU_GROUPS, DAZ_GROUPS, read_cmu


def rig_from_bones(bones, name="Armature"):
    """A RigDescription from ``[(bone, parent name or None, head, tail), ...]`` in any order."""
    index = {b[0]: i for i, b in enumerate(bones)}
    return RigDescription(names=tuple(b[0] for b in bones),
                          parents=[-1 if b[1] is None else index[b[1]] for b in bones],
                          heads=[b[2] for b in bones] or np.zeros((0, 3)),
                          tails=[b[3] for b in bones] or np.zeros((0, 3)), name=name, orientation=np.eye(3))

# BVH files are Y up, facing +Z; Blender's importer turns (x, y, z) into (x, -z, y).
BVH_TO_BLENDER = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])


# --- rig builders ---------------------------------------------------------------------------------------------

def build_rig(name, center, left, right_name, prefix=""):
    """A RigDescription from parent-first (bone, parent, head) lists: ``center`` bones, ``left`` bones and their
    mirror images (x -> -x) named by ``right_name``. A bone's tail is its first child's head; a leaf points on
    along its parent's direction for half that bone's length."""
    left_names = {b for b, _, _ in left}
    right = [(right_name(b), right_name(p) if p in left_names else p, (-h[0], h[1], h[2])) for b, p, h in left]
    bones = center + left + right
    heads = {b: np.array(h, dtype=float) for b, _, h in bones}
    first_child = {}
    for b, p, _ in bones:
        if p is not None:
            first_child.setdefault(p, b)
    out = []
    for b, p, _ in bones:
        if b in first_child:
            tail = heads[first_child[b]]
        else:
            step = heads[b] - heads[p] if p is not None else np.array([0.0, 0.0, 0.1])
            tail = heads[b] + 0.5 * step if np.linalg.norm(step) > 0 else heads[b] + [0.0, 0.0, 0.05]
        out.append((prefix + b, None if p is None else prefix + p, heads[b], tail))
    return rig_from_bones(out, name=name)


def fingers(names, start, parent, spacing=0.032, count=3):
    """Finger chains from the hand bone ``parent`` at ``start``: per (name, (dx, dy)) item, bones name1..count
    (or name(k) for a callable name) along +X from start + (dx, dy, 0)."""
    out = []
    for finger, (dx, dy) in names.items():
        prev = parent
        for k in range(1, count + 1):
            bone = finger(k) if callable(finger) else f"{finger}{k}"
            out.append((bone, prev, (start[0] + dx + (k - 1) * spacing, start[1] + dy, start[2])))
            prev = bone
    return out


FINGER_SPREAD = {"Thumb": (0.03, -0.035), "Index": (0.095, -0.02), "Middle": (0.1, 0.0), "Ring": (0.095, 0.02),
                 "Pinky": (0.085, 0.04)}


def mixamo_rig(prefix="mixamorig:", name="Mixamo"):
    center = [
        ("Hips", None, (0, 0, 1.0)), ("Spine", "Hips", (0, 0.01, 1.1)), ("Spine1", "Spine", (0, 0.01, 1.22)),
        ("Spine2", "Spine1", (0, 0.01, 1.36)), ("Neck", "Spine2", (0, 0, 1.5)), ("Head", "Neck", (0, -0.01, 1.6)),
        ("HeadTop_End", "Head", (0, -0.01, 1.78)),
    ]
    hand = (0.71, 0.02, 1.45)
    left = [
        ("LeftShoulder", "Spine2", (0.06, 0.01, 1.45)), ("LeftArm", "LeftShoulder", (0.18, 0.02, 1.45)),
        ("LeftForeArm", "LeftArm", (0.45, 0.02, 1.45)), ("LeftHand", "LeftForeArm", hand),
        *fingers({f"LeftHand{f}": d for f, d in FINGER_SPREAD.items()}, hand, "LeftHand", count=4),
        ("LeftUpLeg", "Hips", (0.09, 0, 0.95)), ("LeftLeg", "LeftUpLeg", (0.09, 0.01, 0.52)),
        ("LeftFoot", "LeftLeg", (0.09, 0.03, 0.09)), ("LeftToeBase", "LeftFoot", (0.09, -0.09, 0.02)),
        ("LeftToe_End", "LeftToeBase", (0.09, -0.16, 0.02)),
    ]
    return build_rig(name, center, left, lambda b: b.replace("Left", "Right"), prefix=prefix)


def mixamo_groups(prefix="mixamorig:"):
    groups = {"root": ["Hips"], "trunk": ["Spine", "Spine1", "Spine2"], "head": ["Neck", "Head"]}
    for s, side in (("L", "Left"), ("R", "Right")):
        groups.update({f"arm.{s}": [f"{side}Shoulder", f"{side}Arm", f"{side}ForeArm"], f"hand.{s}": [f"{side}Hand"],
                       f"leg.{s}": [f"{side}UpLeg", f"{side}Leg"], f"foot.{s}": [f"{side}Foot"]})
    return BoneMap({g: [prefix + b for b in bones] for g, bones in groups.items()})


def unreal_rig(spine_count=3, name="UE"):
    """UE4 (spine_01..03, neck_01) or UE5 (spine_01..05, neck_01..02) mannequin with twist and IK bones."""
    spine_z = np.linspace(1.06, 1.36, spine_count)
    center = [("root", None, (0, 0, 0)), ("pelvis", "root", (0, 0.01, 0.97))]
    for k, z in enumerate(spine_z, 1):
        center.append((f"spine_0{k}", "pelvis" if k == 1 else f"spine_0{k - 1}", (0, 0.01, z)))
    chest = f"spine_0{spine_count}"
    necks = ["neck_01"] if spine_count == 3 else ["neck_01", "neck_02"]
    for k, neck in enumerate(necks):
        center.append((neck, chest if k == 0 else necks[k - 1], (0, 0, 1.5 + 0.04 * k)))
    center += [("head", necks[-1], (0, -0.01, 1.59)),
               ("ik_foot_root", "root", (0, 0, 0)), ("ik_hand_root", "root", (0, 0, 0)),
               ("ik_hand_gun", "ik_hand_root", (-0.71, 0.02, 1.42))]
    hand = (0.71, 0.02, 1.42)
    left = [
        ("clavicle_l", chest, (0.04, 0.01, 1.45)), ("upperarm_l", "clavicle_l", (0.17, 0.02, 1.42)),
        ("lowerarm_l", "upperarm_l", (0.45, 0.02, 1.42)), ("hand_l", "lowerarm_l", hand),
        ("upperarm_twist_01_l", "upperarm_l", (0.31, 0.02, 1.42)),
        ("lowerarm_twist_01_l", "lowerarm_l", (0.58, 0.02, 1.42)),
        *fingers({(lambda k, f=f: f"{f.lower()}_0{k}_l"): d for f, d in FINGER_SPREAD.items()}, hand, "hand_l"),
        ("thigh_l", "pelvis", (0.09, 0.01, 0.94)), ("calf_l", "thigh_l", (0.09, 0.02, 0.51)),
        ("foot_l", "calf_l", (0.09, 0.04, 0.12)), ("ball_l", "foot_l", (0.09, -0.09, 0.03)),
        ("thigh_twist_01_l", "thigh_l", (0.09, 0.015, 0.73)), ("calf_twist_01_l", "calf_l", (0.09, 0.03, 0.32)),
        ("ik_foot_l", "ik_foot_root", (0.09, 0.04, 0.12)), ("ik_hand_l", "ik_hand_gun", hand),
    ]
    return build_rig(name, center, left, lambda b: re.sub(r"_l$", "_r", b))


def unreal_groups(spine_count=3):
    groups = {"root": ["pelvis"], "trunk": [f"spine_0{k}" for k in range(1, spine_count + 1)],
              "head": ["neck_01", "head"] if spine_count == 3 else ["neck_01", "neck_02", "head"]}
    for s, x in (("L", "l"), ("R", "r")):
        groups.update({f"arm.{s}": [f"clavicle_{x}", f"upperarm_{x}", f"lowerarm_{x}"], f"hand.{s}": [f"hand_{x}"],
                       f"leg.{s}": [f"thigh_{x}", f"calf_{x}"], f"foot.{s}": [f"foot_{x}"]})
    return BoneMap(groups)


def genesis_rig(name="Genesis8"):
    """Daz Genesis 8 naming: ...Bend bones carry the joints, ...Twist bones split the limbs in two."""
    center = [
        ("hip", None, (0, 0, 1.0)), ("pelvis", "hip", (0, 0, 1.0)),
        ("abdomenLower", "hip", (0, 0.01, 1.03)), ("abdomenUpper", "abdomenLower", (0, 0.01, 1.11)),
        ("chestLower", "abdomenUpper", (0, 0.01, 1.21)), ("chestUpper", "chestLower", (0, 0.01, 1.32)),
        ("neckLower", "chestUpper", (0, 0, 1.47)), ("neckUpper", "neckLower", (0, -0.005, 1.52)),
        ("head", "neckUpper", (0, -0.01, 1.58)),
    ]
    hand = (0.71, 0.02, 1.42)
    left = [
        ("lCollar", "chestUpper", (0.03, 0.01, 1.43)), ("lShldrBend", "lCollar", (0.17, 0.02, 1.42)),
        ("lShldrTwist", "lShldrBend", (0.3, 0.02, 1.42)), ("lForearmBend", "lShldrTwist", (0.45, 0.02, 1.42)),
        ("lForearmTwist", "lForearmBend", (0.58, 0.02, 1.42)), ("lHand", "lForearmTwist", hand),
        *fingers({f"l{f}": d for f, d in FINGER_SPREAD.items()}, hand, "lHand"),
        ("lEye", "head", (0.03, -0.08, 1.66)),
        ("lThighBend", "pelvis", (0.08, 0.01, 0.95)), ("lThighTwist", "lThighBend", (0.08, 0.015, 0.75)),
        ("lShin", "lThighTwist", (0.08, 0.02, 0.52)), ("lFoot", "lShin", (0.08, 0.04, 0.09)),
        ("lToe", "lFoot", (0.08, -0.1, 0.02)),
    ]
    return build_rig(name, center, left, lambda b: "r" + b[1:])


def genesis_groups():
    groups = {"root": ["hip"], "trunk": ["abdomenLower", "abdomenUpper", "chestLower", "chestUpper"],
              "head": ["neckLower", "neckUpper", "head"]}
    for s, x in (("L", "l"), ("R", "r")):
        groups.update({f"arm.{s}": [f"{x}Collar", f"{x}ShldrBend", f"{x}ForearmBend"], f"hand.{s}": [f"{x}Hand"],
                       f"leg.{s}": [f"{x}ThighBend", f"{x}Shin"], f"foot.{s}": [f"{x}Foot"]})
    return BoneMap(groups)


def bvh_rig(clip, name):
    """A BVH clip's rest skeleton the way Blender's importer builds it, in the file's axes (Y up)."""
    heads = np.zeros((len(clip.names), 3))
    for j, p in enumerate(clip.parents):
        heads[j] = clip.offsets[j] + (heads[p] if p >= 0 else 0.0)
    return RigDescription(names=clip.names, parents=clip.parents, heads=heads, tails=heads + clip.tail_offsets(),
                          name=name, orientation=BVH_TO_BLENDER)


def cmu_rig():
    return bvh_rig(read_cmu("cmu_07_01_walk.bvh"), "cmu_07_01_walk")


def daz_bvh_rig():
    return bvh_rig(read_cmu("cmu_daz_02_01_walk.bvh"), "cmu_daz_02_01_walk")


def daz_bvh_groups():
    return BoneMap(DAZ_GROUPS)


# (rig factory, expected map, preset label)
NAMED_RIGS = {
    "mixamo": (mixamo_rig, mixamo_groups, "Mixamo"),
    "mixamo1_underscore": (lambda: mixamo_rig(prefix="mixamorig1_"), lambda: mixamo_groups("mixamorig1_"), "Mixamo"),
    "motionbuilder_plain": (lambda: mixamo_rig(prefix=""), lambda: mixamo_groups(""), "MotionBuilder/CMU"),
    "motionbuilder_namespace": (lambda: mixamo_rig(prefix="Character1:"), lambda: mixamo_groups("Character1:"),
                                "MotionBuilder/CMU with a namespace"),
    "ue4": (unreal_rig, unreal_groups, "Unreal mannequin"),
    "ue5": (lambda: unreal_rig(5), lambda: unreal_groups(5), "Unreal mannequin"),
    "genesis8": (genesis_rig, genesis_groups, "Daz"),
    "cmu_bvh": (cmu_rig, lambda: BoneMap(CMU_GROUPS), "MotionBuilder/CMU"),
    "daz_bvh": (daz_bvh_rig, daz_bvh_groups, "Daz"),
}


def renamed(desc, names, name=None):
    return RigDescription(names=names, parents=desc.parents, heads=desc.heads, tails=desc.tails,
                          name=name or desc.name, orientation=desc.orientation)


def rename_map(bone_map, old, new):
    lookup = dict(zip(old, new))
    return BoneMap({g: [lookup[b] for b in bones] for g, bones in bone_map.groups.items()})


def without(desc, doomed):
    """The rig without the bones for which doomed(name) is true, nor anything below them."""
    keep = []
    for i, name in enumerate(desc.names):
        j = i
        while j >= 0 and not doomed(desc.names[j]):
            j = desc.parents[j]
        if j < 0:
            keep.append(i)
    new_index = {old: k for k, old in enumerate(keep)}
    return RigDescription(names=[desc.names[i] for i in keep],
                          parents=[new_index.get(int(desc.parents[i]), -1) for i in keep],
                          heads=desc.heads[keep], tails=desc.tails[keep], name=desc.name,
                          orientation=desc.orientation)


# --- presets --------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("kind", NAMED_RIGS)
def test_presets_map_named_rigs(kind):
    make_rig, make_groups, label = NAMED_RIGS[kind]
    desc = make_rig()
    bone_map = map_rig(desc)
    assert bone_map == make_groups()
    assert bone_map.source == label
    assert bone_map.problems(desc) == [] and bone_map.missing() == []


@pytest.mark.parametrize("kind", NAMED_RIGS)
def test_detection_alone_finds_what_the_presets_find(kind):
    make_rig, make_groups, _ = NAMED_RIGS[kind]
    bone_map = detect_map(make_rig())
    assert bone_map == make_groups()
    assert bone_map.source == "detected from the hierarchy"


@pytest.mark.parametrize("spine_count", [3, 5])
def test_unreal_twist_and_ik_bones_are_never_chain_bones(spine_count):
    desc = unreal_rig(spine_count)
    for bone_map in (map_rig(desc), detect_map(desc)):
        used = {b for _, b in bone_map.items()}
        assert not {b for b in used if "twist" in b or b.startswith("ik_")}
        assert "root" not in used  # the UE root bone lies on the floor; the pelvis is the body's root


def test_mixamo_prefix_is_only_stripped_when_every_bone_has_it():
    desc = mixamo_rig()
    # One foreign-named bone: the preset misses that group and detection takes over, keeping the real names.
    names = ["Whatever" if n == "mixamorig:LeftFoot" else n for n in desc.names]
    bone_map = map_rig(renamed(desc, names))
    assert bone_map.source == "detected from the hierarchy"
    assert bone_map.bones("foot.L") == ("Whatever",)
    assert bone_map.bones("leg.L") == ("mixamorig:LeftUpLeg", "mixamorig:LeftLeg")


def test_optional_slots_that_break_a_chain_are_left_out():
    # A clavicle hanging from the chest beside the upper arm (not above it) cannot lead the arm chain.
    desc = mixamo_rig(prefix="")
    parents = desc.parents.copy()
    parents[desc.index("LeftArm")] = desc.index("Spine2")
    bone_map = map_rig(RigDescription(desc.names, parents, desc.heads, desc.tails, name="Loose clavicle"))
    assert bone_map.bones("arm.L") == ("LeftArm", "LeftForeArm")
    assert bone_map.bones("arm.R") == ("RightShoulder", "RightArm", "RightForeArm")


def generated_like_rig(bent_split):
    """A Rigify-generated-like rig: DEF- bones (arms and legs split in two with '.001' children) and ORG- bones
    forming proper chains. With ``bent_split`` DEF-upper_arm.L points away from the elbow."""
    center = [("root", None, (0, 0, 0))]
    for prefix in ("ORG-", "DEF-"):
        center += [(f"{prefix}spine", "root", (0, 0.05, 1.0)),
                   (f"{prefix}spine.001", f"{prefix}spine", (0, 0.02, 1.15)),
                   (f"{prefix}spine.002", f"{prefix}spine.001", (0, 0, 1.29)),
                   (f"{prefix}spine.003", f"{prefix}spine.002", (0, 0, 1.47)),
                   (f"{prefix}spine.004", f"{prefix}spine.003", (0, 0.01, 1.66)),
                   (f"{prefix}spine.005", f"{prefix}spine.004", (0, -0.01, 1.72)),
                   (f"{prefix}spine.006", f"{prefix}spine.005", (0, -0.02, 1.78))]
    left = [
        ("ORG-shoulder.L", "ORG-spine.003", (0.02, -0.07, 1.6)),
        ("ORG-upper_arm.L", "ORG-shoulder.L", (0.2, 0.03, 1.58)),
        ("ORG-forearm.L", "ORG-upper_arm.L", (0.44, 0.09, 1.45)), ("ORG-hand.L", "ORG-forearm.L", (0.66, 0.05, 1.31)),
        ("ORG-thigh.L", "ORG-spine", (0.1, 0.01, 1.07)), ("ORG-shin.L", "ORG-thigh.L", (0.1, -0.03, 0.54)),
        ("ORG-foot.L", "ORG-shin.L", (0.1, 0.02, 0.09)), ("ORG-toe.L", "ORG-foot.L", (0.1, -0.09, 0.02)),
        # As generated: DEF-shoulder.L and DEF-upper_arm.L hang from ORG-shoulder.L, DEF-thigh.L from ORG-spine.
        ("DEF-shoulder.L", "ORG-shoulder.L", (0.02, -0.07, 1.6)),
        ("DEF-upper_arm.L", "ORG-shoulder.L", (0.2, 0.03, 1.58)),
        ("DEF-upper_arm.L.001", "DEF-upper_arm.L", (0.32, 0.2 if bent_split else 0.06, 1.515)),
        ("DEF-forearm.L", "DEF-upper_arm.L.001", (0.44, 0.09, 1.45)),
        ("DEF-forearm.L.001", "DEF-forearm.L", (0.55, 0.07, 1.38)),
        ("DEF-hand.L", "DEF-forearm.L.001", (0.66, 0.05, 1.31)),
        ("DEF-thigh.L", "ORG-spine", (0.1, 0.01, 1.07)), ("DEF-thigh.L.001", "DEF-thigh.L", (0.1, -0.01, 0.805)),
        ("DEF-shin.L", "DEF-thigh.L.001", (0.1, -0.03, 0.54)), ("DEF-shin.L.001", "DEF-shin.L", (0.1, -0.005, 0.315)),
        ("DEF-foot.L", "DEF-shin.L.001", (0.1, 0.02, 0.09)), ("DEF-toe.L", "DEF-foot.L", (0.1, -0.09, 0.02)),
    ]
    return build_rig("rig", center, left, lambda b: b.replace(".L", ".R"))


def test_generated_rigify_rig_maps_to_def_bones_with_split_segments():
    bone_map = map_rig(generated_like_rig(bent_split=False))
    assert bone_map.source == "Rigify generated rig (DEF- bones)"
    assert bone_map.bones("trunk") == ("DEF-spine.001", "DEF-spine.002", "DEF-spine.003")
    assert bone_map.bones("arm.L") == ("DEF-upper_arm.L", "DEF-forearm.L")  # DEF-shoulder.L is not above them
    assert bone_map.bones("leg.R") == ("DEF-thigh.R", "DEF-shin.R")
    assert bone_map.bones("hand.L") == ("DEF-hand.L",) and bone_map.bones("foot.R") == ("DEF-foot.R",)


def test_generated_rigify_rig_falls_back_to_org_bones_when_a_split_segment_bends():
    desc = generated_like_rig(bent_split=True)
    problems = dict((label, p) for label, _, p in preset_maps(desc))["Rigify generated rig (DEF- bones)"]
    assert problems == [f"arm.{s}: 'DEF-upper_arm.{s}' is split ('DEF-upper_arm.{s}.001' follows) but the next "
                        f"joint is not along it" for s in "LR"]
    bone_map = map_rig(desc)
    assert bone_map.source == "Rigify generated rig (ORG- bones)"
    assert bone_map.bones("arm.L") == ("ORG-shoulder.L", "ORG-upper_arm.L", "ORG-forearm.L")


# --- detection ------------------------------------------------------------------------------------------------

MARKER_STYLES = {
    "none": lambda stem, s: stem,
    "dot": lambda stem, s: f"{stem}.{s}",
    "underscore_lower": lambda stem, s: f"{stem}_{s.lower()}",
    "prefix_lower": lambda stem, s: f"{s.lower()}_{stem}",
    "word_prefix": lambda stem, s: {"L": "Left", "R": "Right"}[s] + stem.capitalize(),
    "word_suffix": lambda stem, s: stem + {"L": "_Left", "R": "_Right"}[s],
    "daz_style": lambda stem, s: s.lower() + stem.capitalize(),
    "space": lambda stem, s: f"{s} {stem}",
}


def invented_names(desc, style, order):
    """bone_017-like names in a shuffled numbering, with a side marker in ``style`` where the bone is sided."""
    sides = [side_of_name(n) for n in desc.names]
    return [MARKER_STYLES[style](f"bone_{k:03d}", s) if s else f"bone_{k:03d}" for k, s in zip(order, sides)]


def random_rotation(draw_angles):
    a, b, c = draw_angles
    rx = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    ry = np.array([[np.cos(b), 0, np.sin(b)], [0, 1, 0], [-np.sin(b), 0, np.cos(b)]])
    rz = np.array([[np.cos(c), -np.sin(c), 0], [np.sin(c), np.cos(c), 0], [0, 0, 1]])
    return rx @ ry @ rz


@settings(deadline=None, max_examples=50)
@given(kind=st.sampled_from(sorted(NAMED_RIGS)), style=st.sampled_from(sorted(MARKER_STYLES)),
       seed=st.integers(0, 2**32 - 1), scale=st.floats(0.01, 100.0),
       angles=st.tuples(*[st.floats(-np.pi, np.pi)] * 3), shift=st.tuples(*[st.floats(-10.0, 10.0)] * 3))
def test_detection_ignores_names_order_placement_and_armature_rotation(kind, style, seed, scale, angles, shift):
    make_rig, make_groups, _ = NAMED_RIGS[kind]
    desc = make_rig()
    rng = np.random.default_rng(seed)
    order = rng.permutation(len(desc))
    names = invented_names(desc, style, rng.permutation(len(desc)))
    # World positions of the moved rig; stored in armature space under a random object rotation.
    world_heads = scale * (desc.heads @ desc.orientation.T) + shift
    world_tails = scale * (desc.tails @ desc.orientation.T) + shift
    rotation = random_rotation(angles)  # armature -> world
    new_of_old = {old: new for new, old in enumerate(order)}
    moved = RigDescription(
        names=[names[old] for old in order],
        parents=[new_of_old[int(desc.parents[old])] if desc.parents[old] >= 0 else -1 for old in order],
        heads=world_heads[order] @ rotation, tails=world_tails[order] @ rotation, name="Invented",
        orientation=rotation)
    expected = rename_map(make_groups(), desc.names, names)
    assert map_rig(moved) == expected


@pytest.mark.parametrize("kind", ["mixamo", "ue5", "cmu_bvh"])
def test_detection_without_markers_takes_sides_from_x_and_swaps_them_in_a_mirror(kind):
    make_rig, make_groups, _ = NAMED_RIGS[kind]
    desc = make_rig()
    names = invented_names(desc, "none", range(len(desc)))
    plain = renamed(desc, names)
    assert detect_map(plain) == rename_map(make_groups(), desc.names, names)
    # Mirrored in x (world), the same bones serve the other side.
    flip = desc.orientation.T @ np.diag([-1.0, 1.0, 1.0]) @ desc.orientation
    mirrored = RigDescription(names, desc.parents, desc.heads @ flip.T, desc.tails @ flip.T,
                              orientation=desc.orientation)
    swapped = {g.replace(".L", ".X").replace(".R", ".L").replace(".X", ".R"): b
               for g, b in detect_map(mirrored).groups.items()}
    assert BoneMap(swapped) == detect_map(plain)


def test_a_rig_without_neck_and_head_maps_without_the_head_group():
    desc = without(mixamo_rig(), lambda n: n == "mixamorig:Neck")
    for bone_map in (map_rig(desc), detect_map(desc)):
        assert "head" not in bone_map.groups and bone_map.missing() == []


# --- rigs that cannot be mapped -----------------------------------------------------------------------------

def tail_chain():
    return rig_from_bones(
        [(f"tail_{k}", f"tail_{k - 1}" if k else None, (0, 0.2 * k, 1.0), (0, 0.2 * k + 0.2, 1.0)) for k in range(8)],
        name="Tail")


def quadruped():
    """A horizontal body with four legs going down, a neck and head in front, a tail behind (like Rigify's
    quadruped metarig, invented names)."""
    center = [("hips", None, (0, 0.45, 0.8)), ("back_1", "hips", (0, 0.3, 0.8)), ("back_2", "back_1", (0, 0.1, 0.8)),
              ("back_3", "back_2", (0, -0.1, 0.8)), ("chest", "back_3", (0, -0.3, 0.82)),
              ("neck", "chest", (0, -0.45, 0.9)), ("skull", "neck", (0, -0.6, 1.0)),
              ("tail_1", "hips", (0, 0.6, 0.8)), ("tail_2", "tail_1", (0, 0.8, 0.75))]
    left = []
    for end, attach, y in (("hind", "hips", 0.45), ("front", "chest", -0.3)):
        left += [(f"{end}_upper.L", attach, (0.12, y, 0.7)),
                 (f"{end}_lower.L", f"{end}_upper.L", (0.12, y + 0.05, 0.4)),
                 (f"{end}_paw.L", f"{end}_lower.L", (0.12, y, 0.08)),
                 (f"{end}_toe.L", f"{end}_paw.L", (0.12, y - 0.08, 0.01))]
    return build_rig("Quadruped", center, left, lambda b: b.replace(".L", ".R"))


def assert_one_line(message, rig_name):
    assert "\n" not in message
    assert message.startswith(f"Cannot map rig '{rig_name}': no ")


def test_a_tail_chain_cannot_be_mapped():
    with pytest.raises(MappingError) as caught:
        map_rig(tail_chain())
    message = str(caught.value)
    assert_one_line(message, "Tail")
    assert "no left leg found (looked for thigh.L/" in message
    assert message.endswith("no bone branches into legs and a spine (from 'tail_0' the bones form one chain))")


def test_a_four_legged_rig_cannot_be_mapped():
    desc = quadruped()
    with pytest.raises(MappingError) as caught:
        map_rig(desc)
    message = str(caught.value)
    assert_one_line(message, "Quadruped")
    assert message.startswith("Cannot map rig 'Quadruped': no upright trunk found (looked for spine.001/spine_01/")
    # From the hips, the body rises no higher than the head, less than half as much as the hind legs are long.
    z = {n: (h[2], t[2]) for n, h, t in zip(desc.names, desc.heads, desc.tails)}
    above = max(max(z[n]) for n in desc.names if not n.startswith(("hind", "tail", "hips"))) - z["hips"][0]
    legs = z["hind_upper.L"][0] - z["hind_paw.L"][0]
    assert above < 0.5 * legs
    assert f"only {above:.3g} rises above 'hips', whose legs are {legs:.3g} long" in message


@pytest.mark.parametrize("doomed, what", [
    ("LeftUpLeg", "left leg"),
    ("RightUpLeg", "right leg"),
    ("LeftForeArm", "left hand"),  # the arm ends at the upper arm (without LeftHand it maps with no hand bone)
    ("RightShoulder", "right arm"),
])
def test_a_rig_missing_a_limb_gets_a_message_naming_it(doomed, what):
    desc = mixamo_rig(prefix="")
    # No preset names, but the side markers (Left/Right) remain.
    desc = without(renamed(desc, [f"bone_{n}" for n in desc.names], name="Invented"), lambda n: n == f"bone_{doomed}")
    with pytest.raises(MappingError) as caught:
        map_rig(desc)
    assert_one_line(str(caught.value), "Invented")
    assert f"no {what} found" in str(caught.value)


def test_a_named_rig_missing_a_bone_names_where_the_arm_stops():
    desc = without(mixamo_rig(), lambda n: n in ("mixamorig:RightHand", "mixamorig:RightForeArm"))
    with pytest.raises(MappingError) as caught:
        map_rig(desc)
    message = str(caught.value)
    assert_one_line(message, "Mixamo")
    # Detection got further than the preset (to the hand): it names the bone where the arm stops.
    assert message.endswith("no right hand found (looked for hand.R/hand_r/rHand/RightHand, or a bone at the end "
                            "of the right arm; the right arm ends at 'mixamorig:RightArm' with no hand below it)")


def test_an_empty_armature_cannot_be_mapped():
    empty = rig_from_bones([], name="Empty")
    with pytest.raises(MappingError, match=r"^Cannot map rig 'Empty': it has no bones$"):
        map_rig(empty)


# --- BoneMap --------------------------------------------------------------------------------------------------

def test_bone_map_orders_groups_and_round_trips_through_items():
    bone_map = BoneMap({"head": ["Neck", "Head"], "hand.L": ["LeftHand"], "root": ["Hips"]}, source="x")
    assert list(bone_map.groups) == ["root", "hand.L", "head"]
    assert bone_map.items() == [("root", "Hips"), ("hand.L", "LeftHand"), ("head", "Neck"), ("head", "Head")]
    assert BoneMap.from_items(bone_map.items()) == bone_map  # source does not take part in ==
    assert bone_map.missing() == [g for g in REQUIRED_GROUPS if g not in ("root", "hand.L")]
    assert set(GROUPS) - set(REQUIRED_GROUPS) == {"head"}


def edited(bone_map, **groups):
    new = dict(bone_map.groups)
    new.update({g.replace("_", "."): bones for g, bones in groups.items()})
    return BoneMap(new)


@pytest.mark.parametrize("edit, problem", [
    (dict(arm_L=["LeftArm", "LeftShoulder", "LeftForeArm"]), "arm.L: 'LeftShoulder' does not hang below 'LeftArm'"),
    (dict(trunk=["Spine", "Spine2", "Spine1"]), "trunk: 'Spine1' does not hang below 'Spine2'"),
    (dict(hand_R=["LeftHand"]), "bone 'LeftHand' is in both hand.L and hand.R"),
    (dict(foot_L=["RightFoot"]), "bone 'RightFoot' is in both foot.L and foot.R"),
    (dict(leg_L=["LeftUpLeg"], foot_L=["LeftToeBase"]), None),  # a shorter leg still fits: no problem
    (dict(hand_L=["RightHand"], hand_R=["LeftHand"]), "hand.L: 'RightHand' does not hang below 'LeftForeArm'"),
    (dict(root=["Hips", "Spine"], trunk=["Spine1", "Spine2"]), "root must be one bone, not 2"),
    (dict(leg_R=[]), "no bones in group 'leg.R'"),
    (dict(arm_X=["LeftArm"]), "unknown group 'arm.X'"),
    (dict(head=["Neck", "Skull"]), "head: no bone 'Skull'"),
])
def test_bone_map_problems_name_what_is_wrong(edit, problem):
    desc = mixamo_rig(prefix="")
    bone_map = edited(map_rig(desc), **edit)
    problems = bone_map.problems(desc)
    if problem is None:
        assert problems == []
        return
    assert problem in problems


def test_bone_map_rejects_a_zero_length_segment():
    desc = rig_from_bones([("a", None, (0, 0, 0), (0, 0, 1)), ("b", "a", (0, 0, 0), (0, 0, 1)),
                                      ("c", "b", (0, 0, 1), (0, 0, 2))], name="Zero")
    assert BoneMap({"trunk": ["a", "b", "c"]}).problems(desc)[-1] == \
        "trunk: 'a' has no length (its head is where 'b' starts)"


# --- names and descriptions -----------------------------------------------------------------------------------

@pytest.mark.parametrize("name, side", [
    ("hand.L", "L"), ("DEF-forearm.R.001", "R"), ("thigh_l", "L"), ("upperarm_twist_01_r", "R"), ("l_arm", "L"),
    ("L Hand", "L"), ("Bip01 R Thigh", "R"), ("LeftUpLeg", "L"), ("mixamorig:RightHand", "R"), ("lShldrBend", "L"),
    ("rForeArm", "R"), ("RHipJoint", "R"), ("LThumb", "L"), ("leftEye", "L"), ("arm_Right", "R"), ("HAND_L", "L"),
    ("spine.001", None), ("Hips", None), ("LowerBack", None), ("neckLower", None), ("ball", None), ("Rib", None),
    ("leftright", None), ("LR", None), ("hand.L.R", None),
])
def test_side_markers(name, side):
    assert side_of_name(name) == side


@pytest.mark.parametrize("kwargs, message", [
    (dict(names=["a", "a"], parents=[-1, 0], heads=np.zeros((2, 3)), tails=np.ones((2, 3))), "'a' is used twice"),
    (dict(names=["a", "b"], parents=[-1, 2], heads=np.zeros((2, 3)), tails=np.ones((2, 3))), "out of range"),
    (dict(names=["a", "b"], parents=[1, 0], heads=np.zeros((2, 3)), tails=np.ones((2, 3))), "its own ancestor"),
    (dict(names=["a"], parents=[-1], heads=[[0, 0, np.nan]], tails=[[0, 0, 1]]), "NaN/inf"),
    (dict(names=["a", "b"], parents=[-1], heads=np.zeros((2, 3)), tails=np.ones((2, 3))), "2 names but parents"),
    (dict(names=["a"], parents=[-1], heads=[[0, 0, 0]], tails=[[0, 0, 1]], orientation=np.eye(4)), "3x3"),
])
def test_rig_description_rejects_malformed_input(kwargs, message):
    with pytest.raises(ValueError, match=re.escape(message)):
        RigDescription(**kwargs)
