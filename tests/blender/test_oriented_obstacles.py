"""Obstacles as the user sees them: a rotated mesh's own bounding box (oriented), not the larger axis-aligned box
around it, on a rig and an obstacle that are both rotated (bpy.ops.fullbody_adjust.adjust_pose)."""

import bpy
import numpy as np
from mathutils import Euler, Matrix

from .scene_tools import Pose, add_rig, chain_joints, effector_bone, place, residuals, slot

UNIT_CORNERS = [(x, y, z) for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]
FACES = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]


def _samples(joints, count=400):
    """Points along the chain's segments (S,3), ends included."""
    t = np.linspace(0.0, 1.0, count)[:, None]
    return np.concatenate([a + t * (b - a) for a, b in zip(joints[:-1], joints[1:])])


def test_the_arm_keeps_out_of_a_rotated_box_but_not_out_of_its_axis_aligned_box():
    obj = add_rig("basic")
    obj.matrix_world = Matrix.Translation((0.2, 0.5, 0.0)) @ Euler((0.1, 0.0, 0.5)).to_matrix().to_4x4()
    bpy.ops.fullbody_adjust.create_targets()
    pose = Pose(obj)
    arm = pose.to_world(chain_joints(obj, pose, "arm.L"))
    elbow, wrist, shoulder = arm[-2], arm[-1], arm[-3]
    # A slab along the forearm, 3 cm below it on the side away from the upper arm: its faces follow the arm, so
    # its axis-aligned box (world axes) reaches over the forearm.
    u = (wrist - elbow) / np.linalg.norm(wrist - elbow)
    n = np.cross(u, [0.0, 0.0, 1.0])
    n /= np.linalg.norm(n)
    if (shoulder - elbow) @ n < 0.0:
        n = -n
    v = np.cross(u, n)
    half = np.array([0.3, 0.12, 0.12])  # along u, n, v
    centre = 0.5 * (elbow + wrist) - (half[1] + 0.03) * n
    mesh = bpy.data.meshes.new("Slab")
    mesh.from_pydata(UNIT_CORNERS, [], FACES)
    slab = bpy.data.objects.new("Slab", mesh)
    world = np.eye(4)
    world[:3, :3] = np.column_stack([u, n, v]) * half
    world[:3, 3] = centre
    slab.matrix_world = Matrix(world.tolist())
    bpy.context.scene.collection.objects.link(slab)
    bpy.context.view_layer.update()
    corners = np.array([slab.matrix_world @ vertex.co for vertex in mesh.vertices])
    lo, hi = corners.min(axis=0), corners.max(axis=0)

    def in_box(points):
        local = (points - centre) @ np.column_stack([u, n, v]) / half
        return np.all(np.abs(local) <= 1.0, axis=-1)

    def in_aligned_box(points):
        return np.all((points >= lo) & (points <= hi), axis=-1)

    assert not in_box(_samples(arm)).any() and in_aligned_box(_samples(arm[-2:])).any()  # the set-up itself

    # The hand reaches 2 cm further along its forearm and 1 cm toward the slab.
    goal = wrist + 0.02 * u - 0.01 * n
    place(slot(obj, "hand.L").target, goal)
    assert bpy.ops.fullbody_adjust.adjust_pose() == {'FINISHED'}
    after = Pose(obj)
    assert residuals(obj)["hand.L"] < 1e-4 * after.height()
    arm_after = after.to_world(chain_joints(obj, after, "arm.L"))
    assert not in_box(_samples(arm_after)).any()
    # It did not keep out of the space the axis-aligned box adds: the forearm still passes through it.
    assert in_aligned_box(_samples(arm_after[-2:])).any()
    # The hand moved as asked, so the solve did run with the slab in the way.
    assert np.linalg.norm(after.to_world(after.head(effector_bone(obj, "hand.L"))) - wrist) > 0.015
