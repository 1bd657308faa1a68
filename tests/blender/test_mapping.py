"""Bone mapping on real Blender rigs (bone_mapping/, read and stored by bridge/rig/mapping.py), through the bpy wheel: the Rigify metarigs and a
generated Rigify rig, the shared BVH clips imported with io_anim_bvh, Mixamo and Unreal armatures built with
their real names; describing armatures, and storing the map on the armature object."""

import math

import bpy
import numpy as np
import pytest

from fullbody_adjust.bone_mapping import BoneMap, MappingError, RigDescription, detect_map, map_rig
from fullbody_adjust.bridge.rig.mapping import describe_armature, ensure_map, is_typed, load_map, read_map, store_map
from tests.helpers.bvh import CMU_GROUPS, MOCAP_DIR
from tests.test_mapping_rules import (
    daz_bvh_groups,
    invented_names,
    mixamo_groups,
    mixamo_rig,
    rename_map,
    renamed,
    tail_chain,
    unreal_groups,
    unreal_rig,
)


def rigify_metarig(full=False):
    if "rigify" not in bpy.context.preferences.addons:
        bpy.ops.preferences.addon_enable(module="rigify")
    if full:
        bpy.ops.object.armature_human_metarig_add()
    else:
        bpy.ops.object.armature_basic_human_metarig_add()
    return bpy.context.object


def import_bvh(filename, scale=0.056444):
    import addon_utils  # importable once bpy is

    addon_utils.enable("io_anim_bvh", default_set=True)
    bpy.ops.import_anim.bvh(filepath=str(MOCAP_DIR / filename), global_scale=scale)
    return bpy.context.object


def armature_from(desc, rotation=(0.0, 0.0, 0.0)):
    """A new armature object with desc's bones (armature space) and the given object rotation (Euler XYZ)."""
    data = bpy.data.armatures.new(desc.name)
    obj = bpy.data.objects.new(desc.name, data)
    bpy.context.scene.collection.objects.link(obj)
    obj.rotation_euler = rotation
    bpy.context.view_layer.objects.active = obj
    bpy.ops.object.mode_set(mode='EDIT')
    bones = [data.edit_bones.new(name) for name in desc.names]
    for bone, parent, head, tail in zip(bones, desc.parents, desc.heads, desc.tails):
        bone.head, bone.tail = head, tail
        bone.parent = bones[parent] if parent >= 0 else None
    bpy.ops.object.mode_set(mode='OBJECT')
    return obj


def rigify_groups(prefix=""):
    groups = {"root": ["spine"], "trunk": ["spine.001", "spine.002", "spine.003"],
              "head": ["spine.004", "spine.005", "spine.006"]}
    for s in "LR":
        groups.update({f"arm.{s}": [f"shoulder.{s}", f"upper_arm.{s}", f"forearm.{s}"], f"hand.{s}": [f"hand.{s}"],
                       f"leg.{s}": [f"thigh.{s}", f"shin.{s}"], f"foot.{s}": [f"foot.{s}"]})
    return BoneMap({g: [prefix + b for b in bones] for g, bones in groups.items()})


def assert_detection_agrees(desc, expected, style="none"):
    """Detection alone, with every name replaced (side markers in ``style``), finds the same bones."""
    names = invented_names(desc, style, range(len(desc)))
    assert detect_map(renamed(desc, names)) == rename_map(expected, desc.names, names)


# --- describing armatures -----------------------------------------------------------------------------------

def test_describe_armature_reads_names_parents_and_rest_positions():
    obj = rigify_metarig()
    obj.rotation_euler = (0.3, -0.2, 1.1)
    obj.scale = (2.0, 2.0, 2.0)
    bpy.context.view_layer.update()
    desc = describe_armature(obj)
    bones = obj.data.bones
    assert desc.name == obj.name and desc.names == tuple(b.name for b in bones)
    assert [desc.names[p] if p >= 0 else None for p in desc.parents] == \
        [b.parent.name if b.parent else None for b in bones]
    np.testing.assert_allclose(desc.heads, [b.head_local for b in bones], atol=1e-6)
    np.testing.assert_allclose(desc.tails, [b.tail_local for b in bones], atol=1e-6)
    # orientation: the object's rotation without its scale.
    rotation = np.array(obj.matrix_world.to_3x3()) / 2.0
    np.testing.assert_allclose(desc.orientation, rotation, atol=1e-6)
    np.testing.assert_allclose(desc.orientation @ desc.orientation.T, np.eye(3), atol=1e-6)


def test_describe_armature_rejects_other_objects():
    mesh = bpy.data.objects.new("Cube", bpy.data.meshes.new("Cube"))
    with pytest.raises(MappingError, match=r"^Cannot map 'Cube': it is not an armature$"):
        describe_armature(mesh)


# --- presets and detection on real rigs ---------------------------------------------------------------------

@pytest.mark.parametrize("full", [False, True], ids=["basic", "full_human"])
def test_rigify_metarigs(full):
    obj = rigify_metarig(full)
    assert len(obj.data.bones) == (159 if full else 29)
    desc = describe_armature(obj)
    bone_map = map_rig(desc)
    assert bone_map == rigify_groups() and bone_map.source == "Rigify metarig"
    assert_detection_agrees(desc, bone_map)


def test_generated_rigify_rig_maps_its_def_bones():
    rigify_metarig()
    bpy.ops.pose.rigify_generate()
    rig = bpy.context.object
    assert rig.name == "rig" and "DEF-upper_arm.L.001" in rig.data.bones
    bone_map = map_rig(describe_armature(rig))
    assert bone_map.source == "Rigify generated rig (DEF- bones)"
    expected = rigify_groups("DEF-").groups
    # DEF-shoulder hangs from ORG-shoulder, not above DEF-upper_arm: the arms start at the upper arm.
    expected.update({f"arm.{s}": (f"DEF-upper_arm.{s}", f"DEF-forearm.{s}") for s in "LR"})
    assert bone_map == BoneMap(expected)
    # The first of each split pair is the chain bone: its .001 continues it towards the next chain joint.
    bones = rig.data.bones
    for first, nxt in (("DEF-upper_arm.L", "DEF-forearm.L"), ("DEF-thigh.R", "DEF-shin.R")):
        assert bones[first + ".001"].parent.name == first
        direction = np.array(bones[first].tail_local - bones[first].head_local)
        to_next = np.array(bones[nxt].head_local - bones[first].head_local)
        assert np.dot(direction, to_next) / np.linalg.norm(direction) / np.linalg.norm(to_next) > math.cos(1e-3)


def test_cmu_bvh_import():
    obj = import_bvh("cmu_07_01_walk.bvh")
    desc = describe_armature(obj)
    bone_map = map_rig(desc)
    assert bone_map == BoneMap(CMU_GROUPS) and bone_map.source == "MotionBuilder/CMU"
    assert_detection_agrees(desc, bone_map, style="dot")


def test_daz_bvh_import():
    obj = import_bvh("cmu_daz_02_01_walk.bvh", scale=0.01)
    names = {b.name for b in obj.data.bones}
    assert {"hip", "abdomen", "chest", "neck", "head", "lCollar", "lShldr", "lForeArm", "lHand", "lThigh", "lShin",
            "lFoot", "lButtock", "rCollar", "rHand", "rFoot"} <= names
    desc = describe_armature(obj)
    bone_map = map_rig(desc)
    assert bone_map == daz_bvh_groups() and bone_map.source == "Daz"
    assert_detection_agrees(desc, bone_map)


@pytest.mark.parametrize("make_rig, make_groups, label", [
    (mixamo_rig, mixamo_groups, "Mixamo"),
    (unreal_rig, unreal_groups, "Unreal mannequin"),
    (lambda: unreal_rig(5), lambda: unreal_groups(5), "Unreal mannequin"),
], ids=["mixamo", "ue4", "ue5"])
def test_built_armatures_with_real_names(make_rig, make_groups, label):
    obj = armature_from(make_rig())
    desc = describe_armature(obj)
    bone_map = map_rig(desc)
    assert bone_map == make_groups() and bone_map.source == label
    assert not [b for _, b in bone_map.items() if "twist" in b]
    assert_detection_agrees(desc, bone_map)


def test_an_fbx_style_armature_with_y_up_bones_under_a_rotated_object():
    # As FBX imports often come: bones stored Y up, the object rotated +90 degrees about X to stand it up.
    upright = mixamo_rig()
    to_world = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])  # rotation X +90
    y_up = RigDescription(upright.names, upright.parents, upright.heads @ to_world, upright.tails @ to_world,
                          name="FBX")
    obj = armature_from(y_up, rotation=(math.pi / 2, 0.0, 0.0))
    bpy.context.view_layer.update()
    desc = describe_armature(obj)
    np.testing.assert_allclose(desc.orientation, to_world, atol=1e-6)
    assert_detection_agrees(desc, mixamo_groups())


def test_quadruped_metarig_cannot_be_mapped():
    if "rigify" not in bpy.context.preferences.addons:
        bpy.ops.preferences.addon_enable(module="rigify")
    bpy.ops.object.armature_basic_quadruped_metarig_add()
    obj = bpy.context.object
    with pytest.raises(MappingError) as caught:
        ensure_map(obj)
    message = str(caught.value)
    assert "\n" not in message
    # Its spine, hind legs and head have Rigify names; the front legs hang from shoulders, with no upper arm.
    assert message.startswith(f"Cannot map rig '{obj.name}': no left arm found (looked for upper_arm.L/")
    assert message.endswith("other bones have Rigify metarig names)")
    assert len(obj.fullbody_adjust.bone_map) == 0


# --- the stored map -----------------------------------------------------------------------------------------

def stored_items(obj):
    return [(item.group, item.bone) for item in obj.fullbody_adjust.bone_map]


def test_store_and_load_round_trip():
    obj = rigify_metarig()
    assert load_map(obj) is None
    bone_map = rigify_groups()
    store_map(obj, bone_map)
    assert stored_items(obj) == bone_map.items()
    loaded = load_map(obj)
    assert loaded == bone_map and loaded.source == "stored"
    store_map(obj, BoneMap({"root": ["spine"]}))  # replaces, never appends
    assert stored_items(obj) == [("root", "spine")]


def test_ensure_map_maps_stores_and_keeps_a_fitting_edit():
    obj = rigify_metarig()
    first = ensure_map(obj)
    assert first == rigify_groups() and stored_items(obj) == first.items()
    # The user drops the clavicle from the left arm in the panel: still fits, so it is kept.
    items = obj.fullbody_adjust.bone_map
    index = next(i for i, item in enumerate(items) if (item.group, item.bone) == ("arm.L", "shoulder.L"))
    items.remove(index)
    kept = ensure_map(obj)
    assert kept.source == "stored" and kept.bones("arm.L") == ("upper_arm.L", "forearm.L")
    # A blank row the user added but did not fill is ignored.
    blank = items.add()
    blank.group = "head"
    assert ensure_map(obj) == kept


def test_ensure_map_maps_again_when_its_own_map_no_longer_fits():
    obj = rigify_metarig()
    ensure_map(obj)
    assert not is_typed(obj)
    obj.data.bones["forearm.L"].name = "lower_arm.L"  # the stored map now names a missing bone
    remapped = ensure_map(obj)
    assert remapped.source == "detected from the hierarchy"  # no preset has lower_arm.L
    assert remapped.bones("arm.L") == ("shoulder.L", "upper_arm.L", "lower_arm.L")
    assert load_map(obj) == remapped and not is_typed(obj)


def test_a_typed_map_that_no_longer_fits_is_kept_and_its_problem_named():
    obj = rigify_metarig()
    ensure_map(obj)
    # The user drops the clavicle from the left arm in the panel: the map is now theirs.
    items = obj.fullbody_adjust.bone_map
    items.remove(next(i for i, item in enumerate(items) if item.bone == "shoulder.L"))
    assert is_typed(obj)
    obj.data.bones["forearm.L"].name = "lower_arm.L"  # then renames a bone it names
    before = stored_items(obj)
    for read in (ensure_map, read_map):
        with pytest.raises(MappingError) as caught:
            read(obj)
        assert str(caught.value) == (f"The bone map typed on '{obj.name}' does not fit it: arm.L: no bone "
                                     f"'forearm.L'; fix it in Bone Mapping or press Map Again")
    assert stored_items(obj) == before  # never replaced by detection
    # Fixed by hand in the panel: used as typed.
    next(item for item in items if item.bone == "forearm.L").bone = "lower_arm.L"
    fixed = ensure_map(obj)
    assert fixed.source == "stored" and fixed.bones("arm.L") == ("upper_arm.L", "lower_arm.L")
    assert stored_items(obj) == [(g, "lower_arm.L" if b == "forearm.L" else b) for g, b in before]


@pytest.mark.parametrize("edit, problem", [
    (("hand.L", "hand.L", "hand.R"), "bone 'hand.R' is in both hand.L and hand.R"),
    (("foot.R", "foot.R", "toe.R"), None),  # a shorter foot still fits
    (("foot.R", "foot.R", "breast.R"), "foot.R: 'breast.R' does not hang below 'shin.R'"),
    (("arm.L", "forearm.L", "heel.02.L"), "arm.L: 'heel.02.L' does not hang below 'upper_arm.L'"),
    (("leg.L", "thigh.L", "thigh.R"), "bone 'thigh.R' is in both leg.L and leg.R"),
    (("hand.R", "hand.R", ""), None),  # no hand bone: the right wrist is the end of forearm.R
    (("head", "spine.006", "Skull"), "head: no bone 'Skull'"),
])
def test_a_hand_typed_map_is_checked_not_replaced(edit, problem):
    obj = rigify_metarig()
    store_map(obj, rigify_groups(), typed=True)
    group, old, new = edit
    next(item for item in obj.fullbody_adjust.bone_map if (item.group, item.bone) == (group, old)).bone = new
    typed = stored_items(obj)
    if problem is None:
        assert ensure_map(obj).source == "stored" and stored_items(obj) == typed
        return
    with pytest.raises(MappingError) as caught:
        ensure_map(obj)
    message = str(caught.value)
    assert "\n" not in message
    assert message.startswith(f"The bone map typed on '{obj.name}' does not fit it: {problem}")
    assert stored_items(obj) == typed


def test_a_stored_map_whose_legs_go_up_is_refused():
    obj = rigify_metarig()
    groups = dict(rigify_groups().groups)
    groups["leg.L"], groups["foot.L"] = ("spine.001",), ("spine.003",)  # a "leg" up the spine
    groups["trunk"] = ("spine.002",)
    store_map(obj, BoneMap(groups), typed=True)
    with pytest.raises(MappingError, match=r"foot\.L: the ankle \('spine\.003'\) is not below the hip joint "
                                           r"\('spine\.001'\)"):
        ensure_map(obj)


def test_ensure_map_on_a_rig_named_otherwise():
    obj = rigify_metarig()
    expected = rename_map(rigify_groups(), [b.name for b in obj.data.bones], [f"b{k}" for k in range(29)])
    for k, bone in enumerate(list(obj.data.bones)):
        bone.name = f"b{k}"
    assert ensure_map(obj) == expected
    assert load_map(obj) == expected


def test_ensure_map_on_an_unmappable_rig_raises_and_leaves_the_stored_map():
    obj = armature_from(tail_chain())
    store_map(obj, BoneMap({"root": ["tail_0"]}))
    with pytest.raises(MappingError) as caught:
        ensure_map(obj)
    assert str(caught.value).startswith("Cannot map rig 'Tail': no left leg found (looked for thigh.L/")
    assert stored_items(obj) == [("root", "tail_0")]
