"""Target slots, target empties and reading them back (bridge/rig/targets.py), through the bpy wheel."""

import math

import bpy
import numpy as np
import pytest

from fullbody_adjust.bridge.errors import AdjustError
from fullbody_adjust.bridge.rig.targets import (
    DEFAULT_PRIORITY,
    EFFECTORS,
    NO_ENABLED_TARGET,
    create_targets,
    ensure_slots,
    read_target_frames,
    read_targets,
)
from tests.helpers.rotations import euler_xyz

# Basic metarig bones whose heads are the effectors (it has no "head" bone: its top spine bone is the head).
EFFECTOR_BONES = {"hand.L": "hand.L", "hand.R": "hand.R", "foot.L": "foot.L", "foot.R": "foot.R",
                  "head": "spine.006"}



def effector_positions(obj, effectors=EFFECTORS):
    world = np.array(obj.matrix_world)
    return {e: world[:3, :3] @ np.array(obj.pose.bones[EFFECTOR_BONES[e]].head) + world[:3, 3] for e in effectors}


def location(ob):
    return np.array(ob.matrix_world.translation)


def snapshot(obj):
    """Everything the bad-input paths must leave alone."""
    slots = [(s.effector, s.target.name if s.target else None, s.priority, s.enabled)
             for s in obj.fullbody_adjust.targets]
    # The user's own transform values (matrix_world is a cache the depsgraph refreshes); repr so that a NaN
    # location compares equal to itself.
    objects = sorted((ob.name, repr((tuple(ob.location), tuple(ob.rotation_euler), tuple(ob.scale))),
                      ob.parent.name if ob.parent else None, tuple(c.name for c in ob.users_collection))
                     for ob in bpy.data.objects)
    return slots, objects, sorted(c.name for c in bpy.data.collections), bpy.context.scene.frame_current


# ---------------------------------------------------------------- slots

def test_ensure_slots_makes_one_slot_per_effector_with_default_priorities(rig):
    slots = ensure_slots(rig)
    assert [s.effector for s in slots] == list(EFFECTORS)
    assert [s.priority for s in slots] == [DEFAULT_PRIORITY[e] for e in EFFECTORS]
    assert DEFAULT_PRIORITY["foot.L"] > DEFAULT_PRIORITY["hand.L"] > DEFAULT_PRIORITY["head"]
    # No target yet, so nothing is enabled (an enabled empty slot would read as a missing target).
    assert all(s.target is None and not s.enabled for s in slots)


def test_ensure_slots_restores_order_and_drops_duplicates_keeping_settings(rig):
    marker = bpy.data.objects.new("marker", None)
    bpy.context.scene.collection.objects.link(marker)
    slots = rig.fullbody_adjust.targets
    for effector, priority in (("head", 7), ("foot.R", 5), ("head", 9)):
        slot = slots.add()
        slot.effector, slot.priority, slot.enabled = effector, priority, True
    slots[1].target = marker

    ensure_slots(rig)
    ensure_slots(rig)  # a second call changes nothing
    by_effector = {s.effector: s for s in slots}
    assert [s.effector for s in slots] == list(EFFECTORS)
    assert (by_effector["head"].priority, by_effector["head"].enabled) == (7, True)  # first head slot kept
    assert (by_effector["foot.R"].priority, by_effector["foot.R"].target) == (5, marker)
    assert by_effector["hand.L"].priority == DEFAULT_PRIORITY["hand.L"]


# ---------------------------------------------------------------- create_targets

def test_create_targets_places_named_empties_in_their_own_collection(rig):
    positions = effector_positions(rig)
    empties = create_targets(bpy.context, rig, positions, size=0.05)

    collection = bpy.data.collections[f"{rig.name}_targets"]
    assert collection.name in bpy.context.scene.collection.children
    assert set(empties) == set(EFFECTORS)
    for slot in rig.fullbody_adjust.targets:
        empty = empties[slot.effector]
        assert empty.name == f"{rig.name}_{slot.effector}"
        assert empty.type == 'EMPTY' and empty.users_collection == (collection,)
        assert empty.empty_display_size == pytest.approx(0.05)
        np.testing.assert_allclose(location(empty), positions[slot.effector], atol=1e-6)
        assert slot.target == empty
        # Hands and feet are switched on; the optional head target is linked but left off.
        assert slot.enabled == (slot.effector != "head")


def test_create_targets_twice_reuses_the_empties_and_keeps_user_placement(rig):
    first_positions = effector_positions(rig, ("hand.L", "hand.R", "foot.L", "foot.R"))
    first = create_targets(bpy.context.scene, rig, first_positions, size=0.05)
    first["hand.L"].location = (0.5, -1.0, 1.5)  # the user moves a target
    moved = location(first["hand.L"])

    shifted = {e: p + 1.0 for e, p in first_positions.items()}
    second = create_targets(bpy.context, rig, shifted, size=0.05)
    assert second == first
    empty_names = sorted(ob.name for ob in bpy.data.objects if ob.type == 'EMPTY')
    assert empty_names == sorted(f"{rig.name}_{e}" for e in first_positions)  # no "....001" copies
    assert len(bpy.data.collections) == 1
    np.testing.assert_allclose(location(first["hand.L"]), moved, atol=1e-6)
    np.testing.assert_allclose(location(first["foot.R"]), first_positions["foot.R"], atol=1e-6)

    create_targets(bpy.context, rig, shifted, size=0.05, reset=True)
    for effector, position in shifted.items():
        np.testing.assert_allclose(location(first[effector]), position, atol=1e-6)


def test_create_targets_brings_back_a_target_deleted_from_the_scene(rig):
    positions = effector_positions(rig, ("hand.L",))
    empty = create_targets(bpy.context, rig, positions, size=0.05)["hand.L"]
    empty.location = (3.0, 3.0, 3.0)
    empty.users_collection[0].objects.unlink(empty)  # what deleting in the UI leaves: the slot still holds it

    again = create_targets(bpy.context, rig, positions, size=0.05)["hand.L"]
    assert again == empty and again.name == f"{rig.name}_hand.L"
    assert bpy.context.scene in again.users_scene
    np.testing.assert_allclose(location(again), positions["hand.L"], atol=1e-6)


def test_create_targets_with_a_non_finite_position_changes_nothing(rig):
    positions = effector_positions(rig)
    positions["foot.L"] = np.array([0.0, math.inf, 0.0])
    before = snapshot(rig)
    with pytest.raises(AdjustError) as caught:
        create_targets(bpy.context, rig, positions, size=0.05)
    assert str(caught.value) == f"The current position of foot.L on '{rig.name}' is not finite"
    assert snapshot(rig) == before


# ---------------------------------------------------------------- read_targets

def test_read_targets_returns_world_positions_rotations_and_priorities(rig):
    empties = create_targets(bpy.context, rig, effector_positions(rig), size=0.05)
    hand = empties["hand.L"]
    hand.location = (0.3, -0.2, 1.1)
    hand.rotation_euler = (0.4, -0.7, 1.2)
    hand.scale = (2.0, 3.0, 0.5)  # scale must not leak into the rotation
    rig.fullbody_adjust.targets[EFFECTORS.index("foot.R")].priority = 8

    specs = read_targets(rig)
    assert [s.effector for s in specs] == ["hand.L", "hand.R", "foot.L", "foot.R"]  # head is off
    by_effector = {s.effector: s for s in specs}
    np.testing.assert_allclose(by_effector["hand.L"].position, [0.3, -0.2, 1.1], atol=1e-6)
    np.testing.assert_allclose(by_effector["hand.L"].rotation, euler_xyz(0.4, -0.7, 1.2), atol=1e-6)
    for effector in ("hand.R", "foot.L", "foot.R"):
        np.testing.assert_allclose(by_effector[effector].position, location(empties[effector]), atol=1e-6)
        np.testing.assert_allclose(by_effector[effector].rotation, np.eye(3), atol=1e-6)
    assert [s.priority for s in specs] == [2, 2, 3, 8]
    assert by_effector["hand.L"].name == hand.name


def test_a_target_scaled_to_zero_along_an_axis_reads_that_axis_as_zero(rig):
    """The rotation part divides each column by its length, a zero-length one by 1: no NaN reaches the solve."""
    empties = create_targets(bpy.context, rig, effector_positions(rig, ("hand.L",)), size=0.05)
    hand = empties["hand.L"]
    hand.rotation_euler = (0.4, -0.7, 1.2)
    hand.scale = (0.0, 2.0, 0.5)
    rotation = read_targets(rig)[0].rotation
    assert np.isfinite(rotation).all()
    np.testing.assert_array_equal(rotation[:, 0], 0.0)
    np.testing.assert_allclose(rotation[:, 1:], euler_xyz(0.4, -0.7, 1.2)[:, 1:], atol=1e-6)


def test_read_targets_follows_a_parented_target(rig):
    empties = create_targets(bpy.context, rig, effector_positions(rig, ("hand.R",)), size=0.05)
    holder = bpy.data.objects.new("holder", None)
    bpy.context.scene.collection.objects.link(holder)
    holder.location = (1.0, 2.0, 3.0)
    holder.rotation_euler = (0.0, 0.0, math.pi / 2)
    target = empties["hand.R"]
    target.parent = holder  # identity parent inverse: the location is in the holder's space
    target.location = (0.5, 0.0, 0.25)

    expected = euler_xyz(0.0, 0.0, math.pi / 2) @ np.array([0.5, 0.0, 0.25]) + [1.0, 2.0, 3.0]
    np.testing.assert_allclose(read_targets(rig)[0].position, expected, atol=1e-6)

    holder.location = (-1.0, 0.0, 0.0)  # moving the parent moves the target, no manual update needed
    expected = euler_xyz(0.0, 0.0, math.pi / 2) @ np.array([0.5, 0.0, 0.25]) + [-1.0, 0.0, 0.0]
    np.testing.assert_allclose(read_targets(rig)[0].position, expected, atol=1e-6)


def animate_with_frame_drivers(ob, expressions):
    """Drive ob.location[i] by an expression of the (sub)frame, so any frame's value is known exactly."""
    for index, expression in enumerate(expressions):
        ob.driver_add("location", index).driver.expression = expression


def test_read_target_frames_samples_animated_targets_and_restores_the_frame(rig):
    empties = create_targets(bpy.context, rig, effector_positions(rig), size=0.05)
    animate_with_frame_drivers(empties["hand.L"], ("frame / 10", "-frame / 5", "1.0"))
    scene = bpy.context.scene
    scene.frame_set(4)

    frames = [1, 6, 11, 8.5]
    positions, rotations = read_target_frames(rig, frames, rotations=True)
    assert positions.shape == (4, len(EFFECTORS), 3) and rotations.shape == (4, len(EFFECTORS), 3, 3)
    for row, frame in enumerate(frames):
        np.testing.assert_allclose(positions[row, 0], [frame / 10, -frame / 5, 1.0], atol=1e-6)
        np.testing.assert_allclose(positions[row, 3], location(empties["foot.R"]), atol=1e-6)
    assert np.isnan(positions[:, EFFECTORS.index("head")]).all()  # head slot is disabled
    assert not np.isnan(positions[:, :4]).any()
    np.testing.assert_allclose(rotations[:, :4], np.broadcast_to(np.eye(3), (4, 4, 3, 3)), atol=1e-6)
    assert (scene.frame_current, scene.frame_subframe) == (4, 0.0)
    np.testing.assert_allclose(read_target_frames(rig, [6])[0], positions[1], atol=1e-12)


# ---------------------------------------------------------------- bad input: one line, nothing changed

def assert_one_line_error(call, expected, obj):
    before = snapshot(obj)
    with pytest.raises(AdjustError) as caught:
        call()
    assert str(caught.value) == expected and "\n" not in str(caught.value)
    assert snapshot(obj) == before


@pytest.mark.parametrize("read", [read_targets, lambda obj: read_target_frames(obj, [1, 2])],
                         ids=["read_targets", "read_target_frames"])
def test_no_enabled_target(rig, read):
    assert_one_line_error(lambda: read(rig), NO_ENABLED_TARGET, rig)  # no slots at all
    ensure_slots(rig)
    assert_one_line_error(lambda: read(rig), NO_ENABLED_TARGET, rig)  # slots, none enabled
    create_targets(bpy.context, rig, effector_positions(rig), size=0.05)
    for slot in rig.fullbody_adjust.targets:
        slot.enabled = False
    assert_one_line_error(lambda: read(rig), NO_ENABLED_TARGET, rig)
    assert NO_ENABLED_TARGET == "No enabled target: set a target object in the Full Body panel"


@pytest.mark.parametrize("read", [read_targets, lambda obj: read_target_frames(obj, [1, 2])],
                         ids=["read_targets", "read_target_frames"])
def test_deleted_target(rig, read):
    empties = create_targets(bpy.context, rig, effector_positions(rig), size=0.05)
    empty = empties["foot.L"]
    empty.users_collection[0].objects.unlink(empty)  # gone from the scene, still held by the slot
    assert_one_line_error(lambda: read(rig), f"Target '{rig.name}_foot.L' for foot.L is missing from the "
                                             "scene (deleted?)", rig)

    bpy.data.objects.remove(empties["hand.L"])  # removed from the file: the slot's pointer turns None
    slot = rig.fullbody_adjust.targets[EFFECTORS.index("hand.L")]
    assert slot.target is None and slot.enabled
    assert_one_line_error(lambda: read(rig), "Target for hand.L is missing (deleted?)", rig)


def test_non_finite_target_location(rig):
    empties = create_targets(bpy.context, rig, effector_positions(rig), size=0.05)
    hand = empties["hand.R"]
    hand.location = (0.0, math.nan, 0.0)
    expected = f"Target '{hand.name}' for hand.R has a non-finite location"
    assert_one_line_error(lambda: read_targets(rig), expected, rig)
    assert_one_line_error(lambda: read_target_frames(rig, [1]), expected + " at frame 1", rig)

    # Only at some frames (the keyed values are exact whatever the interpolation): the error names the
    # frame and the current frame is restored.
    hand.location = (0.0, 0.0, 0.0)
    hand.keyframe_insert("location", frame=1)
    hand.location = (0.0, 0.0, math.nan)  # (an inf key would be clamped to the float maximum)
    hand.keyframe_insert("location", frame=5)
    bpy.context.scene.frame_set(1)
    assert np.isfinite(read_targets(rig)[1].position).all()
    assert_one_line_error(lambda: read_target_frames(rig, [1, 5]), expected + " at frame 5", rig)
