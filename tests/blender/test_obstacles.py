"""Which meshes are obstacles and their world-space boxes (bridge/reading/obstacles.py), through the bpy wheel."""

import math

import bpy
import numpy as np
import pytest

from fullbody_adjust.bridge.errors import AdjustError
from fullbody_adjust.bridge.reading.obstacles import obstacle_box_frames, obstacle_boxes, obstacle_meshes
from fullbody_adjust.solver.obstacles.boxes import Boxes
from tests.helpers.rotations import euler_xyz

# A cube of half-size 1 around its origin: the same 8 corners as its bound_box, in any order.
UNIT_CORNERS = np.array([(x, y, z) for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=np.float64)



def cube(name, location=(0.0, 0.0, 0.0), rotation=(0.0, 0.0, 0.0), scale=(1.0, 1.0, 1.0), collection=None):
    mesh = bpy.data.meshes.new(name)
    faces = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    mesh.from_pydata(UNIT_CORNERS.tolist(), [], faces)
    ob = bpy.data.objects.new(name, mesh)
    ob.location, ob.rotation_euler, ob.scale = location, rotation, scale
    (collection or bpy.context.scene.collection).objects.link(ob)
    return ob


def expected_corners(local_corners, location, rotation, scale):
    return (euler_xyz(*rotation) @ (np.asarray(local_corners) * scale).T).T + location


def assert_same_corners(actual, expected):
    """Equal as sets of points (the order of bound_box corners is Blender's business)."""
    key = lambda c: np.lexsort(np.round(c, 6).T[::-1])  # noqa: E731
    np.testing.assert_allclose(actual[key(actual)], expected[key(expected)], atol=1e-5)


def names(obs):
    return [ob.name for ob in obs]


def test_default_obstacles_are_visible_meshes_that_do_not_move_with_the_rig(rig):
    cube("wall", location=(1.0, 2.0, 0.5))
    body = cube("body")
    body.modifiers.new("Armature", 'ARMATURE').object = rig
    held = cube("held")
    held.parent = rig
    on_bone = cube("on_bone")
    on_bone.parent, on_bone.parent_type, on_bone.parent_bone = rig, 'BONE', "hand.L"
    socket = bpy.data.objects.new("socket", None)  # an empty on the rig carrying a mesh: still the rig's
    bpy.context.scene.collection.objects.link(socket)
    socket.parent = rig
    grandchild = cube("grandchild")
    grandchild.parent = socket
    constrained = cube("constrained")
    constrained.constraints.new('CHILD_OF').target = rig
    hidden = cube("hidden")
    hidden.hide_set(True)
    switched_off = cube("switched_off")
    switched_off.hide_viewport = True
    other_rig_body = cube("other_rig_body")  # deformed by another armature: an obstacle for this one
    other = bpy.data.objects.new("other", bpy.data.armatures.new("other"))
    bpy.context.scene.collection.objects.link(other)
    other_rig_body.modifiers.new("Armature", 'ARMATURE').object = other

    assert names(obstacle_meshes(rig, bpy.context)) == ["other_rig_body", "wall"]

    # The other rig's body loses its status once this rig deforms it too.
    other_rig_body.modifiers.new("Armature.001", 'ARMATURE').object = rig
    assert names(obstacle_meshes(rig, bpy.context)) == ["wall"]
    assert obstacle_boxes(rig, bpy.context).shape == (1, 8, 3)


def test_a_rotated_scaled_cube_gives_its_transformed_corners(rig):
    location, rotation, scale = np.array([0.4, -1.5, 0.7]), (0.3, -0.5, 1.1), np.array([0.5, 2.0, 1.5])
    cube("box", location=location, rotation=rotation, scale=scale)
    corners = obstacle_boxes(rig, bpy.context)
    assert corners.shape == (1, 8, 3)
    assert_same_corners(corners[0], expected_corners(UNIT_CORNERS, location, rotation, scale))

    # What the solver makes of it: the axis-aligned box enclosing the rotated cube.
    boxes = Boxes.from_corners(corners)
    expected = expected_corners(UNIT_CORNERS, location, rotation, scale)
    np.testing.assert_allclose(boxes.mins[0], expected.min(axis=0), atol=1e-5)
    np.testing.assert_allclose(boxes.maxs[0], expected.max(axis=0), atol=1e-5)


def test_modifiers_count_in_the_box(rig):
    ob = cube("arrayed", location=(0.0, 0.0, 1.0))
    array = ob.modifiers.new("Array", 'ARRAY')
    array.count, array.relative_offset_displace = 3, (1.0, 0.0, 0.0)  # copies side by side along x
    local = UNIT_CORNERS * [3.0, 1.0, 1.0] + [2.0, 0.0, 0.0]  # x from -1 to 5
    assert_same_corners(obstacle_boxes(rig, bpy.context)[0], local + [0.0, 0.0, 1.0])


def test_the_chosen_collection_overrides_the_default(rig):
    cube("outside")
    chosen = bpy.data.collections.new("obstacles")
    bpy.context.scene.collection.children.link(chosen)
    nested = bpy.data.collections.new("nested")
    chosen.children.link(nested)
    hidden = cube("hidden_in_chosen", location=(3.0, 0.0, 0.0), collection=chosen)
    hidden.hide_set(True)  # picked by the user: counts although hidden
    cube("nested_cube", location=(0.0, 3.0, 0.0), scale=(2.0, 2.0, 2.0), collection=nested)
    cube("body_in_chosen", collection=chosen).modifiers.new("Armature", 'ARMATURE').object = rig
    marker = bpy.data.objects.new("marker", None)
    chosen.objects.link(marker)

    assert names(obstacle_meshes(rig, bpy.context)) == ["nested_cube", "outside"]
    rig.fullbody_adjust.obstacles = chosen
    assert names(obstacle_meshes(rig, bpy.context)) == ["hidden_in_chosen", "nested_cube"]
    corners = obstacle_boxes(rig, bpy.context)
    assert_same_corners(corners[0], UNIT_CORNERS + [3.0, 0.0, 0.0])
    assert_same_corners(corners[1], UNIT_CORNERS * 2.0 + [0.0, 3.0, 0.0])


def test_no_obstacles_gives_an_empty_array(rig):
    assert obstacle_boxes(rig, bpy.context).shape == (0, 8, 3)
    assert obstacle_box_frames(rig, bpy.context, [1, 2, 3]).shape == (3, 0, 8, 3)


def test_an_animated_obstacle_gives_a_box_per_frame(rig):
    cube("still", location=(0.0, 5.0, 0.0))
    moving = cube("moving")
    for index, expression in enumerate(("frame / 4", "0.0", "1.0 + frame / 8")):  # exact at any (sub)frame
        moving.driver_add("location", index).driver.expression = expression
    moving.driver_add("rotation_euler", 2).driver.expression = "frame / 10"
    scene = bpy.context.scene
    scene.frame_set(7)

    frames = [1, 4, 10, 2.5]
    boxes = obstacle_box_frames(rig, bpy.context, frames)
    assert boxes.shape == (4, 2, 8, 3)
    assert names(obstacle_meshes(rig, bpy.context)) == ["moving", "still"]
    for row, frame in enumerate(frames):
        expected = expected_corners(UNIT_CORNERS, [frame / 4, 0.0, 1.0 + frame / 8], (0.0, 0.0, frame / 10), 1.0)
        assert_same_corners(boxes[row, 0], expected)
        assert_same_corners(boxes[row, 1], UNIT_CORNERS + [0.0, 5.0, 0.0])
    assert (scene.frame_current, scene.frame_subframe) == (7, 0.0)
    np.testing.assert_allclose(obstacle_boxes(rig, bpy.context), obstacle_box_frames(rig, bpy.context, [7])[0])


def test_a_non_finite_obstacle_is_reported_by_name(rig):
    cube("broken").scale = (1.0, math.nan, 1.0)
    scene = bpy.context.scene
    scene.frame_set(3)
    with pytest.raises(AdjustError, match=r"^Obstacle 'broken' has a non-finite bounding box$"):
        obstacle_boxes(rig, bpy.context)
    with pytest.raises(AdjustError, match=r"^Obstacle 'broken' has a non-finite bounding box at frame 2$"):
        obstacle_box_frames(rig, bpy.context, [2, 4])
    assert scene.frame_current == 3
