"""The per-armature rig cache: a click reuses the map and body model while the rig is unchanged, and never
uses a stale one after the rig's bones or the stored map change."""

import importlib

import bpy
import numpy as np
import pytest


@pytest.fixture
def rig_cache(extension_module_name):
    return importlib.import_module(f"{extension_module_name}.bridge.rig.rig_cache")


def model_bones(rig, group):
    model = rig.model
    return [model.names[i] for i in model.groups[group]]


def rename_bone(obj, old, new):
    obj.data.bones[old].name = new


def add_bone(obj, name, parent):
    bpy.ops.object.mode_set(mode='EDIT')
    bone = obj.data.edit_bones.new(name)
    bone.head, bone.tail = (0.0, 0.3, 1.0), (0.0, 0.3, 1.2)
    bone.parent = obj.data.edit_bones[parent]
    bpy.ops.object.mode_set(mode='OBJECT')


def test_unchanged_rig_is_reused(rig, rig_cache):
    first = rig_cache.rig_of(rig)
    assert rig_cache.rig_of(rig) is first
    rig.fullbody_adjust.margin = 0.2  # a solver setting: not part of the rig
    rig.location.x = 1.0
    assert rig_cache.rig_of(rig) is first


def test_renamed_bone_is_seen(rig, rig_cache):
    bpy.ops.fullbody_adjust.create_targets()
    before = rig_cache.rig_of(rig)
    assert "hand.L" in model_bones(before, "hand.L")
    rename_bone(rig, "hand.L", "wrist_left")
    after = rig_cache.rig_of(rig)
    assert model_bones(after, "hand.L") == ["wrist_left"]
    assert "hand.L" not in after.model.names
    assert bpy.ops.fullbody_adjust.adjust_pose() == {'FINISHED'}
    assert [i.bone for i in rig.fullbody_adjust.bone_map if i.group == "hand.L"] == ["wrist_left"]


def test_added_bone_is_seen(rig, rig_cache):
    before = rig_cache.rig_of(rig)
    add_bone(rig, "prop", "spine.003")
    after = rig_cache.rig_of(rig)
    assert after is not before
    assert len(after.model.names) == len(before.model.names) + 1
    assert "prop" in after.model.names
    assert after.model.names.index("prop") == list(rig.data.bones.keys()).index("prop")



def test_reparented_bone_is_seen(rig, rig_cache):
    """A bone moved under the bone listed before it, a leaf, where it stands: the bones keep their names and order.
    The next model has the new hierarchy."""
    before = rig_cache.rig_of(rig)
    bones = rig.data.bones
    names = list(bones.keys())
    moved = next(bone.name for bone, previous in zip(bones[1:], bones) if not previous.children and
                 bone.parent != previous and not bone.use_connect)
    leaf = names[names.index(moved) - 1]
    bpy.ops.object.mode_set(mode='EDIT')
    rig.data.edit_bones[moved].parent = rig.data.edit_bones[leaf]
    bpy.ops.object.mode_set(mode='OBJECT')
    assert list(rig.data.bones.keys()) == names and rig.data.bones[moved].parent.name == leaf
    after = rig_cache.rig_of(rig)
    assert after is not before
    assert names[after.rest["parents"][names.index(moved)]] == leaf
    assert after.model.parents[after.model.names.index(moved)] == after.model.names.index(leaf)


def test_edited_map_is_used(rig, rig_cache):
    before = rig_cache.rig_of(rig)
    arm = model_bones(before, "arm.L")
    assert len(arm) >= 3, arm  # clavicle, upper arm, forearm
    # Drop the clavicle from the left arm in the stored map, as a user may in the Bone Mapping panel.
    items = rig.fullbody_adjust.bone_map
    index = next(i for i, item in enumerate(items) if item.group == "arm.L" and item.bone == arm[0])
    items.remove(index)
    after = rig_cache.rig_of(rig)
    assert model_bones(after, "arm.L") == arm[1:]
    assert after.bone_map.bones("arm.L") == tuple(arm[1:])


def test_map_that_no_longer_fits_is_mapped_again_unless_typed(rig, rig_cache):
    rig_cache.rig_of(rig)
    # A bone of the map mapping stored is renamed: the rig is mapped afresh (and the map stored again).
    rename_bone(rig, "hand.R", "wrist_right")
    after = rig_cache.rig_of(rig)
    assert model_bones(after, "hand.R") == ["wrist_right"]
    # A row the user typed naming a bone the rig does not have: their map is kept and its problem named.
    next(item for item in rig.fullbody_adjust.bone_map if item.group == "hand.R").bone = "no such bone"
    with pytest.raises(Exception, match=r"does not fit it: hand\.R: no bone 'no such bone'"):
        rig_cache.rig_of(rig)
    assert [i.bone for i in rig.fullbody_adjust.bone_map if i.group == "hand.R"] == ["no such bone"]


def test_rest_data_is_the_rigs_and_rotation_modes_are_read_each_time(rig, rig_cache, extension_module_name):
    pose = importlib.import_module(f"{extension_module_name}.bridge.reading.pose")
    cached = rig_cache.rig_of(rig)
    fresh = pose.read_static(rig)
    static = cached.static(rig)
    assert set(static) == set(fresh)
    for key, value in fresh.items():
        np.testing.assert_array_equal(np.asarray(static[key]), np.asarray(value), err_msg=key)
    rig.pose.bones["forearm.L"].rotation_mode = 'XZY'
    assert rig_cache.rig_of(rig) is cached
    modes = cached.static(rig)["rotation_modes"]
    assert modes[list(rig.data.bones.keys()).index("forearm.L")] == 'XZY'
    assert modes == pose.read_static(rig)["rotation_modes"]
