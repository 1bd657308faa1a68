"""Mapping that reads the body (bone_mapping/body_sides.py, detection.py), without Blender: sides from where
the skeleton faces whatever the object axes, joints from heads whatever importers did to tails, and the one line
a rig that cannot be mapped gets.

The rigs are the synthetic Mixamo, Unreal and CMU skeletons of test_mapping_rules (metres, z up, facing -Y,
their left at +X), turned about z with the turn in the bone data (as `Apply Rotation` leaves a rig), renamed
"Bone", "Bone.001", ... (no side marker), their tails moved as importers move them, or their side labels
mirrored; and small rigs built here shaped like the real characters users bring (a plush toy without spine, a
chibi rig with wrist + hand + prop bones, a robot without hands, a character with IK-style feet).
"""

import math

import numpy as np
import pytest

from fullbody_adjust.bone_mapping import BoneMap, MappingError, RigDescription, body_sides, detect_map, map_rig
from tests.test_mapping_rules import NAMED_RIGS, build_rig, rename_map, renamed, rig_from_bones

TURNS = {"-Y": 0.0, "+X": 90.0, "+Y": 180.0, "-X": 270.0}  # facing after turning a -Y facing rig about z


def turned(desc, degrees):
    """desc with its world positions turned about z, the turn applied to the bone data (orientation kept)."""
    a = math.radians(degrees)
    turn = np.array([[math.cos(a), -math.sin(a), 0.0], [math.sin(a), math.cos(a), 0.0], [0.0, 0.0, 1.0]])
    # Armature space -> world -> turned world -> armature space.
    to_arm = desc.orientation.T @ turn @ desc.orientation
    return RigDescription(desc.names, desc.parents, desc.heads @ to_arm.T, desc.tails @ to_arm.T, name=desc.name,
                          orientation=desc.orientation)


def unnamed(desc):
    """Blender's names for new bones: Bone, Bone.001, ..."""
    names = ["Bone"] + [f"Bone.{k:03d}" for k in range(1, len(desc))]
    return renamed(desc, names, name="Unnamed"), names


def mirrored_labels(names):
    """Left <-> Right in the names: a rig whose labels lie (its 'Left' bones on the character's right)."""
    swap = {"Left": "Right", "Right": "Left", "_l": "_r", "_r": "_l"}
    out = []
    for n in names:
        for a, b in swap.items():
            if a in n:
                n = n.replace(a, b)
                break
        out.append(n)
    return out


def world_facing(desc, bone_map):
    """The facing body_sides reads from a map's legs, as a world vector."""
    sk = desc._skeleton
    legs = [body_sides.Limb(tuple(desc.index(b) for b in bone_map.bones(f"leg.{s}")),
                            desc.index(bone_map.bones(f"foot.{s}")[0])) for s in "LR"]
    lat = body_sides.lateral(sk, *legs)
    sign, clear = body_sides.facing(sk, legs)
    return sign * np.cross([0.0, 0.0, 1.0], lat), clear


@pytest.mark.parametrize("facing", TURNS)
@pytest.mark.parametrize("kind", ["mixamo", "ue4", "cmu_bvh", "genesis8"])
def test_unnamed_rigs_map_with_their_own_left_whatever_they_face(kind, facing):
    make_rig, make_groups, _ = NAMED_RIGS[kind]
    desc = turned(make_rig(), TURNS[facing])
    plain, names = unnamed(desc)
    expected = rename_map(make_groups(), desc.names, names)
    for bone_map in (map_rig(plain), detect_map(plain)):
        assert bone_map == expected and bone_map.source == "detected from the hierarchy"
    # The facing read from the skeleton is the turned one, and it is clear (the toes say it).
    forward, clear = world_facing(plain, expected)
    a = math.radians(TURNS[facing])
    np.testing.assert_allclose(forward, [math.sin(a), -math.cos(a), 0.0], atol=1e-9)
    assert clear
    # The mapped left hand lies on the character's left: up x forward.
    left = np.cross([0.0, 0.0, 1.0], forward)
    sk = plain._skeleton
    hands = [sk.heads[plain.index(expected.bones(f"hand.{s}")[0])] for s in "LR"]
    assert (hands[0] - hands[1]) @ left > 0.5 * np.linalg.norm(hands[0] - hands[1])


@pytest.mark.parametrize("facing", TURNS)
def test_named_rigs_keep_their_names_whatever_they_face(facing):
    make_rig, make_groups, label = NAMED_RIGS["mixamo"]
    bone_map = map_rig(turned(make_rig(), TURNS[facing]))
    assert bone_map == make_groups() and bone_map.source == label


@pytest.mark.parametrize("kind", ["mixamo", "ue4", "cmu_bvh"])
@pytest.mark.parametrize("facing", ["-Y", "+X"])
def test_mirrored_side_labels_yield_to_a_clear_facing(kind, facing):
    """Labels saying Left on the character's right (as on the Godot platformer robot): the toes say clearly
    where it faces, so arm.L is the arm on its own left, whatever the names say."""
    make_rig, make_groups, label = NAMED_RIGS[kind]
    desc = turned(make_rig(), TURNS[facing])
    liars = mirrored_labels(desc.names)
    lying = renamed(desc, liars, name="Liar")
    truth = rename_map(make_groups(), desc.names, liars)  # the bones on each side, under their lying names
    for bone_map in (map_rig(lying), detect_map(lying)):
        assert bone_map == truth
    assert map_rig(lying).source.endswith("sides from the skeleton's facing")


def without_toes_and_bends(desc):
    """The rig with straight legs (knees on the hip - ankle line), no bone below the feet and feet bones
    pointing straight down: nothing in the skeleton says where it faces."""
    sk = desc._skeleton
    heads, tails = desc.heads.copy(), desc.tails.copy()
    keep = []
    for i, name in enumerate(desc.names):
        if any(t in name for t in ("Toe", "ball", "toe")):
            continue
        keep.append(i)
    for name in desc.names:
        for side in ("Left", "Right"):
            if name.endswith(f"{side}Leg"):
                k, hip, ankle = desc.index(name), desc.index(name.replace("Leg", "UpLeg")), \
                    desc.index(name.replace("Leg", "Foot"))
                heads[k] = 0.5 * (heads[hip] + heads[ankle])
                tails[hip] = heads[k]
                tails[k] = heads[ankle]
                tails[ankle] = heads[ankle] - [0.0, 0.0, 0.05]
    assert sk is not None
    new_index = {old: k for k, old in enumerate(keep)}
    return RigDescription([desc.names[i] for i in keep], [new_index.get(int(desc.parents[i]), -1) for i in keep],
                          heads[keep], tails[keep], name="Flat")


def test_names_decide_when_the_skeleton_does_not_say_where_it_faces():
    make_rig, make_groups, _ = NAMED_RIGS["motionbuilder_plain"]
    flat = without_toes_and_bends(make_rig())
    sk = flat._skeleton
    legs = [body_sides.Limb((flat.index(f"{s}UpLeg"), flat.index(f"{s}Leg")), flat.index(f"{s}Foot"))
            for s in ("Left", "Right")]
    assert body_sides.facing(sk, legs) == (0, False)
    # Mirrored labels: with nothing else to go by, the names decide.
    liars = mirrored_labels(flat.names)
    lying = renamed(flat, liars)
    by_name = map_rig(lying)
    assert by_name.bones("leg.L") == ("LeftUpLeg", "LeftLeg") and by_name.bones("hand.L") == ("LeftHand",)
    # No names either: Blender's front view, +X is left.
    plain, names = unnamed(flat)
    bone_map = detect_map(plain)
    assert bone_map == rename_map(make_groups(), flat.names, names) or bone_map.bones("leg.L") == (
        names[flat.index("LeftUpLeg")], names[flat.index("LeftLeg")])
    assert plain._skeleton.heads[plain.index(bone_map.bones("hand.L")[0]), 0] > 0


def importer_tails(desc, kind, seed=0):
    """Tails as importers leave them: 'gltf' far past the next joint (100x along it), 'fbx' along an
    arbitrary bone Y axis (a random direction, the bone's own length)."""
    rng = np.random.default_rng(seed)
    steps = desc.tails - desc.heads
    if kind == "gltf":
        tails = desc.heads + 100.0 * steps
    else:
        directions = rng.normal(size=steps.shape)
        directions /= np.linalg.norm(directions, axis=1, keepdims=True)
        tails = desc.heads + np.linalg.norm(steps, axis=1, keepdims=True) * directions
    return RigDescription(desc.names, desc.parents, desc.heads, tails, name=desc.name, orientation=desc.orientation)


@pytest.mark.parametrize("tails", ["gltf", "fbx"])
@pytest.mark.parametrize("kind", sorted(NAMED_RIGS))
def test_tails_from_importers_change_nothing(kind, tails):
    make_rig, make_groups, label = NAMED_RIGS[kind]
    desc = importer_tails(make_rig(), tails)
    bone_map = map_rig(desc)
    assert bone_map == make_groups() and bone_map.source == label
    plain, names = unnamed(desc)
    assert detect_map(plain) == rename_map(make_groups(), desc.names, names)


# --- rigs shaped like the real characters users bring -------------------------------------------------------

def plush():
    """Godot plush-like: no spine; a big head bone at the hips carries the arms; stubby legs with tall feet."""
    center = [("hips", None, (0, 0, 0.8)), ("head", "hips", (0, 0, 0.8))]
    left = [("upper_arm.L", "head", (0.52, 0, 0.82)), ("forearm.L", "upper_arm.L", (0.65, 0.014, 0.73)),
            ("hand.L", "forearm.L", (0.76, 0, 0.65)),
            ("thigh.L", "hips", (0.19, 0.006, 0.54)), ("shin.L", "thigh.L", (0.19, -0.014, 0.38)),
            ("foot.L", "shin.L", (0.19, 0.011, 0.18)), ("toe.L", "foot.L", (0.19, -0.175, 0.008))]
    desc = build_rig("Plush", center, left, lambda b: b.replace(".L", ".R"))
    tails = desc.tails.copy()
    tails[desc.index("head")] = (0, 0, 1.32)  # the top of the head: nothing follows it
    return RigDescription(desc.names, desc.parents, desc.heads, tails, name="Plush")


def chibi(slots=True):
    """KayKit-like: upper arm straight from the chest (no clavicle), wrist + hand bones, a prop slot bone."""
    center = [("root", None, (0, 0, 0)), ("hips", "root", (0, 0, 0.41)), ("spine", "hips", (0, 0, 0.6)),
              ("chest", "spine", (0, 0, 0.97)), ("head", "chest", (0, 0, 1.24))]
    left = [("upperarm.l", "chest", (0.21, 0, 1.11)), ("lowerarm.l", "upperarm.l", (0.45, 0.014, 1.11)),
            ("wrist.l", "lowerarm.l", (0.71, 0, 1.11)), ("hand.l", "wrist.l", (0.79, 0, 1.11)),
            *([("handslot.l", "hand.l", (0.88, 0, 1.05))] if slots else []),
            ("upperleg.l", "hips", (0.17, 0, 0.52)), ("lowerleg.l", "upperleg.l", (0.17, -0.008, 0.29)),
            ("foot.l", "lowerleg.l", (0.17, 0.019, 0.145)), ("toes.l", "foot.l", (0.17, -0.096, 0.026))]
    return build_rig("Chibi", center, left, lambda b: b.replace(".l", ".r"))


@pytest.mark.parametrize("slots", [True, False])
def test_a_chibi_rig_maps_its_wrist_bones_as_hands(slots):
    bone_map = map_rig(chibi(slots))
    groups = {"root": ["hips"], "trunk": ["spine", "chest"], "head": ["head"]}
    for s, x in (("L", "l"), ("R", "r")):
        groups.update({f"arm.{s}": [f"upperarm.{x}", f"lowerarm.{x}"], f"hand.{s}": [f"wrist.{x}"],
                       f"leg.{s}": [f"upperleg.{x}", f"lowerleg.{x}"], f"foot.{s}": [f"foot.{x}"]})
    assert bone_map == BoneMap(groups)


def test_a_plush_toy_without_spine_maps_its_head_as_the_trunk():
    bone_map = map_rig(plush())
    groups = {"root": ["hips"], "trunk": ["head"]}
    for s in "LR":
        groups.update({f"arm.{s}": [f"upper_arm.{s}", f"forearm.{s}"], f"hand.{s}": [f"hand.{s}"],
                       f"leg.{s}": [f"thigh.{s}", f"shin.{s}"], f"foot.{s}": [f"foot.{s}"]})
    assert bone_map == BoneMap(groups)


def test_a_rig_without_hand_bones_maps_its_wrists_at_the_forearms_ends():
    """A robot's arms: upper arm and forearm, nothing below. The arms are mapped with no hand bone, the wrist
    being where the forearm ends (its tail here: a leaf no longer than the upper arm), said in the map's source."""
    desc = plush()
    keep = [i for i, n in enumerate(desc.names) if not n.startswith("hand")]
    handless = RigDescription([desc.names[i] for i in keep], [keep.index(p) if p >= 0 else -1
                                                             for p in desc.parents[keep]],
                              desc.heads[keep], desc.tails[keep], name="Robot")
    bone_map = map_rig(handless)
    groups = {"root": ["hips"], "trunk": ["head"]}
    for s in "LR":
        groups.update({f"arm.{s}": [f"upper_arm.{s}", f"forearm.{s}"], f"leg.{s}": [f"thigh.{s}", f"shin.{s}"],
                       f"foot.{s}": [f"foot.{s}"]})
    assert bone_map == BoneMap(groups)
    assert bone_map.missing() == [] and bone_map.handless() == {"hand.L": "forearm.L", "hand.R": "forearm.R"}
    assert bone_map.source.endswith("; no hand bones: the left wrist is the end of 'forearm.L' and the right wrist "
                                    "is the end of 'forearm.R'")
    sk = handless._skeleton
    for s in "LR":  # the wrist: the forearm's tail, where the hand's head was
        forearm = handless.index(f"forearm.{s}")
        assert np.allclose(sk.ends[forearm], desc.heads[desc.index(f"hand.{s}")])


def test_ik_style_feet_outside_the_legs_are_named():
    """Quaternius-like: the feet hang from a root bone on the floor, at the ends of shins that end the legs."""
    desc = plush()
    bones = [("Root", None, (0, 0, 0), (0, 0, 0.1))]
    for name, p, head, tail in zip(desc.names, desc.parents, desc.heads, desc.tails):
        parent = "Root" if name.startswith("foot") or p < 0 else desc.names[p]
        bones.append((name, parent, head, tail))
    loose = rig_from_bones(bones, name="Loose feet")
    with pytest.raises(MappingError) as caught:
        map_rig(loose)
    message = str(caught.value)
    assert "\n" not in message
    assert message == ("Cannot map rig 'Loose feet': its left foot 'foot.L' hangs from 'Root', not below the leg's "
                       "last bone 'shin.L' (an IK-style foot), so a moved leg would leave the mesh's foot behind; "
                       "parent 'foot.L' to 'shin.L' (Keep Offset) to use this rig")


def bent(desc, bone, axis, degrees):
    """desc with ``bone`` and everything below it turned about ``axis`` (world) through the bone's head."""
    sk = desc._skeleton
    b = desc.index(bone)
    a = math.radians(degrees)
    k = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    cross = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    turn = np.eye(3) + math.sin(a) * cross + (1 - math.cos(a)) * cross @ cross
    heads, tails = desc.heads.copy(), desc.tails.copy()
    pivot = desc.heads[b]
    for i in sk.subtree(b):
        heads[i] = pivot + turn @ (heads[i] - pivot)
        tails[i] = pivot + turn @ (tails[i] - pivot)
    return RigDescription(desc.names, desc.parents, heads, tails, name=desc.name)


def test_a_rest_taken_mid_stride_maps():
    """As the rest of Kenney's run clip: one thigh swung 50 degrees forward, the other shin kicked back level."""
    make_rig, make_groups, _ = NAMED_RIGS["motionbuilder_plain"]
    desc = bent(make_rig(), "RightUpLeg", (1, 0, 0), -50.0)  # knee forward (-Y)
    desc = bent(desc, "LeftLeg", (1, 0, 0), 90.0)  # foot up behind (+Y) ...
    desc = bent(desc, "LeftFoot", (1, 0, 0), 40.0)  # ... its toes pointing back, as in that clip
    assert desc.heads[desc.index("LeftFoot"), 2] > 0.45  # the left ankle is as high as the knees
    plain, names = unnamed(desc)
    assert detect_map(plain) == rename_map(make_groups(), desc.names, names)


def test_a_clavicle_is_told_by_the_hips_width():
    """A stylised arm (forearm longer than the upper arm, as on Kenney's characters): proportions alone would
    take clavicle + upper arm as the upper arm; the clavicle starts inside the hips' width, the arm outside."""
    make_rig, make_groups, _ = NAMED_RIGS["motionbuilder_plain"]
    desc = make_rig()
    heads, tails = desc.heads.copy(), desc.tails.copy()
    sk = desc._skeleton
    for side, sign in (("Left", 1.0), ("Right", -1.0)):
        for i in sk.subtree(desc.index(f"{side}Hand")):
            heads[i, 0] += sign * 0.2
            tails[i, 0] += sign * 0.2
        tails[desc.index(f"{side}ForeArm"), 0] += sign * 0.2
    long_forearms = RigDescription(desc.names, desc.parents, heads, tails, name="Stylised")
    plain, names = unnamed(long_forearms)
    assert detect_map(plain) == rename_map(make_groups(), desc.names, names)
