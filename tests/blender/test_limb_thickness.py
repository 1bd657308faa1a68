"""Limbs have thickness: an arm skinned to a mesh keeps its mesh out of an obstacle box, and
Margin is the distance its surface keeps from the box, measured on the evaluated (deformed) mesh's vertices after
Adjust Pose (bpy.ops.fullbody_adjust.adjust_pose). Without a mesh, the joints and bones keep out as before."""

import importlib

import bpy
import numpy as np
import pytest

from .scene_tools import Pose, add_box, add_rig, body_axes, chain_joints, evaluated, place, slot

# The cylinders' radii (m): the upper arm thicker than the forearm; the shoulder and spine much thicker (torso).
RADII = {"upper_arm.L": 0.05, "forearm.L": 0.04, "shoulder.L": 0.12, "spine.001": 0.15}
RINGS, SIDES = 9, 16


def skinned_arm(obj):
    """A mesh deformed by ``obj``: a cylinder of RADII[bone] around each bone's joint segment at rest (its head to
    its child's head), every vertex weighted 1 to that bone."""
    bones = obj.data.bones
    points, faces, owner = [], [], []
    for name, radius in RADII.items():
        bone = bones[name]
        head = np.array(bone.head_local)
        end = np.array(bone.children[0].head_local if len(bone.children) == 1 else bone.tail_local)
        if name == "upper_arm.L":
            end = np.array(bones["forearm.L"].head_local)
        elif name == "forearm.L":
            end = np.array(bones["hand.L"].head_local)
        axis = (end - head) / np.linalg.norm(end - head)
        n1 = np.cross(axis, [0.0, 0.0, 1.0] if abs(axis[2]) < 0.9 else [1.0, 0.0, 0.0])
        n1 /= np.linalg.norm(n1)
        n2 = np.cross(axis, n1)
        start = len(points)
        for t in np.linspace(0.0, 1.0, RINGS):
            for k in range(SIDES):
                angle = 2.0 * np.pi * k / SIDES
                points.append(head + t * (end - head) + radius * (np.cos(angle) * n1 + np.sin(angle) * n2))
                owner.append(name)
        for i in range(RINGS - 1):
            for k in range(SIDES):
                a, b = start + i * SIDES + k, start + i * SIDES + (k + 1) % SIDES
                faces.append((a, b, b + SIDES, a + SIDES))
    mesh = bpy.data.meshes.new("Body")
    mesh.from_pydata([p.tolist() for p in points], [], faces)
    body = bpy.data.objects.new("Body", mesh)
    bpy.context.scene.collection.objects.link(body)
    for name in RADII:
        group = body.vertex_groups.new(name=name)
        group.add([i for i, o in enumerate(owner) if o == name], 1.0, 'REPLACE')
    body.modifiers.new("Armature", 'ARMATURE').object = obj
    bpy.context.view_layer.objects.active = obj
    return body, np.array(owner)


def arm_vertices(body, owner):
    """World positions of the evaluated mesh's upper arm and forearm vertices."""
    ev = evaluated(body)
    co = np.empty(len(ev.data.vertices) * 3, dtype=np.float32)
    ev.data.vertices.foreach_get("co", co)
    world = np.array(ev.matrix_world)
    co = co.reshape(-1, 3).astype(np.float64) @ world[:3, :3].T + world[:3, 3]
    return co[np.isin(owner, ["upper_arm.L", "forearm.L"])]


def box_distances(box, points):
    """(n,) each world point's distance to the (axis-aligned, unrotated) box mesh's bounds; 0 inside."""
    corners = np.array([box.matrix_world @ v.co for v in box.data.vertices])
    lo, hi = corners.min(axis=0), corners.max(axis=0)
    return np.linalg.norm(np.maximum(np.maximum(lo - points, points - hi), 0.0), axis=1)


def arm_scene():
    """The basic metarig with targets and its left hand's target in front of it with the elbow bent (0.65 of the
    arm's reach from its base, up and forward), a skinned mesh, and the pose channels at rest."""
    obj = add_rig("basic")
    bpy.ops.fullbody_adjust.create_targets()
    body, owner = skinned_arm(obj)
    pose = Pose(obj)
    up, _left, forward = body_axes(obj, pose)
    arm = chain_joints(obj, pose, "arm.L")
    reach = float(np.linalg.norm(np.diff(arm, axis=0), axis=1).sum())
    direction = (arm[-1] - arm[0]) / np.linalg.norm(arm[-1] - arm[0]) + 0.5 * up + 0.6 * forward
    place(slot(obj, "hand.L").target, pose.to_world(arm[0] + 0.65 * reach * direction / np.linalg.norm(direction)))
    rest = {pb.name: (tuple(pb.location), tuple(pb.rotation_quaternion), tuple(pb.rotation_euler))
            for pb in obj.pose.bones}
    return obj, body, owner, rest


def back_to(obj, rest):
    for name, (location, quaternion, euler) in rest.items():
        pb = obj.pose.bones[name]
        pb.location, pb.rotation_quaternion, pb.rotation_euler = location, quaternion, euler
    bpy.context.view_layer.update()


def adjusted(obj, rest, margin, with_mesh, body):
    """Adjust Pose from ``rest`` with ``margin``; with_mesh False: the mesh's Armature modifier off during the
    solve (the solver sees no mesh), on again for the measure."""
    back_to(obj, rest)
    obj.fullbody_adjust.margin = margin
    body.modifiers["Armature"].show_viewport = with_mesh
    assert bpy.ops.fullbody_adjust.adjust_pose() == {'FINISHED'}
    body.modifiers["Armature"].show_viewport = True
    return Pose(obj)


def test_limb_radii_are_the_arm_bones_not_the_torso(extension_module_name):
    thickness = importlib.import_module(f"{extension_module_name}.bridge.reading.limb_thickness")
    rig_cache = importlib.import_module(f"{extension_module_name}.bridge.rig.rig_cache")
    obj, _body, _owner, _rest = arm_scene()
    # A glove: 300 vertices 20 cm from the wrist weighted 0.3 to the forearm and 0.7 to the hand, whose vertices
    # they are (more than the forearm's own: they would make it thick if they counted for it).
    hand = obj.data.bones["hand.L"]
    angles = np.linspace(0.0, 2.0 * np.pi, 300, endpoint=False)
    ring = np.array(hand.head_local) + 0.2 * np.stack([np.cos(angles), np.zeros_like(angles), np.sin(angles)], 1)
    mesh = bpy.data.meshes.new("Glove")
    mesh.from_pydata(ring.tolist(), [], [])
    glove = bpy.data.objects.new("Glove", mesh)
    bpy.context.scene.collection.objects.link(glove)
    for bone, weight in (("forearm.L", 0.3), ("hand.L", 0.7)):
        glove.vertex_groups.new(name=bone).add(list(range(len(ring))), weight, 'REPLACE')
    glove.modifiers.new("Armature", 'ARMATURE').object = obj
    radii = thickness.limb_radii(obj, rig_cache.rig_of(obj))
    # arm.L: its upper arm's (the thicker of upper arm and forearm), not its shoulder's (the torso's 0.12).
    assert set(radii) == {"arm.L", "trunk"}
    np.testing.assert_allclose(radii["arm.L"], RADII["upper_arm.L"], rtol=1e-5)
    np.testing.assert_allclose(radii["trunk"], RADII["spine.001"], rtol=1e-5)


def test_the_arms_mesh_keeps_out_of_a_box_and_margin_is_its_clearance(extension_module_name):
    adjustment = importlib.import_module(f"{extension_module_name}.bridge.adjustment")
    obj, body, owner, rest = arm_scene()
    free = adjusted(obj, rest, 0.0, True, body)
    # A 10 cm box in the forearm's way: centred a quarter of the way from the elbow to the wrist of the pose
    # solved without it.
    wrist_free, elbow_free = (free.to_world(free.head(b)) for b in ("hand.L", "forearm.L"))
    box = add_box(obj, elbow_free + 0.25 * (wrist_free - elbow_free), 0.1)
    bpy.context.view_layer.update()

    # Without the mesh (the paper's joints and segments): the joints keep out, the mesh does not.
    paper = adjusted(obj, rest, 0.0, False, body)
    paper_distances = box_distances(box, arm_vertices(body, owner))
    paper_in = int((paper_distances == 0.0).sum())
    joints = paper.to_world(chain_joints(obj, paper, "arm.L"))
    assert (box_distances(box, joints) > 0.0).all()
    assert paper_in > 0, "the set-up: the old behaviour lets the mesh into the box"
    print(f"paper (no mesh): {paper_in} of {len(paper_distances)} arm vertices inside")

    for margin in (0.0, 0.05):
        after = adjusted(obj, rest, margin, True, body)
        distances = box_distances(box, arm_vertices(body, owner))
        print(f"margin {margin}: vertices inside {int((distances == 0.0).sum())}, "
              f"nearest vertex {distances.min():.4f} m")
        # float32 vertex and bone positions (~1e-7 m at 1 m) and the solver's tolerance (1e-5): 1e-4 m.
        assert distances.min() >= margin - 1e-4
        goal = np.array(evaluated(slot(obj, "hand.L").target).matrix_world.translation)
        assert np.linalg.norm(after.to_world(after.head("hand.L")) - goal) < 1e-4
    back_to(obj, rest)
    outcome = adjustment.adjust_pose(bpy.context, obj, adjustment.Options(insert_keys=False))
    assert "clearance" not in outcome.reasons[0][0]  # kept in full: nothing eased


def test_a_clearance_the_target_leaves_no_room_for_is_eased_and_said(extension_module_name):
    """A box across the middle of the forearm's way, 9 cm from the target: a 4-5 cm thick forearm cannot keep
    5 cm from it and still reach; the hand reaches, the mesh keeps out of the box, and the reason says how much
    clearance was kept."""
    adjustment = importlib.import_module(f"{extension_module_name}.bridge.adjustment")
    obj, body, owner, rest = arm_scene()
    free = adjusted(obj, rest, 0.0, True, body)
    wrist_free, elbow_free = (free.to_world(free.head(b)) for b in ("hand.L", "forearm.L"))
    box = add_box(obj, 0.5 * (wrist_free + elbow_free), 0.08)
    back_to(obj, rest)
    obj.fullbody_adjust.margin = 0.05
    outcome = adjustment.adjust_pose(bpy.context, obj, adjustment.Options(insert_keys=False))
    hand = list(outcome.effectors).index("hand.L")
    assert outcome.status[0, hand] == "reached" and outcome.residuals[0, hand] < 1e-4
    assert "of its clearance" in outcome.reasons[0, hand], outcome.reasons[0, hand]
    distances = box_distances(box, arm_vertices(body, owner))
    print(f"eased: {outcome.reasons[0, hand]}; nearest vertex {distances.min():.4f} m")
    assert (distances > 0.0).all()


def test_a_mesh_without_the_bones_groups_changes_nothing(extension_module_name):
    """A deformed mesh whose vertex groups name no bone gives no radius: the pose is the one solved without it."""
    thickness = importlib.import_module(f"{extension_module_name}.bridge.reading.limb_thickness")
    rig_cache = importlib.import_module(f"{extension_module_name}.bridge.rig.rig_cache")
    obj, body, _owner, rest = arm_scene()
    free = adjusted(obj, rest, 0.0, True, body)
    wrist_free, elbow_free = (free.to_world(free.head(b)) for b in ("hand.L", "forearm.L"))
    add_box(obj, elbow_free + 0.25 * (wrist_free - elbow_free), 0.1)
    without = adjusted(obj, rest, 0.05, False, body).matrices
    for group in body.vertex_groups:
        group.name = "not_a_bone_" + group.name
    assert thickness.limb_radii(obj, rig_cache.rig_of(obj)) == {}
    np.testing.assert_array_equal(adjusted(obj, rest, 0.05, True, body).matrices, without)


def test_a_generated_rigs_deform_bones_count_for_the_limb_they_lie_along(extension_module_name):
    """On a rig generated by Rigify the mesh is weighted to DEF- bones (two per upper arm and forearm) while the
    solve runs on the ORG- bones: each DEF- bone's vertices count for the ORG- bone it lies along."""
    thickness = importlib.import_module(f"{extension_module_name}.bridge.reading.limb_thickness")
    rig_cache = importlib.import_module(f"{extension_module_name}.bridge.rig.rig_cache")
    bpy.ops.preferences.addon_enable(module="rigify")
    bpy.ops.object.armature_basic_human_metarig_add()
    bpy.ops.pose.rigify_generate()
    rig = bpy.context.active_object
    radii = {"DEF-upper_arm.L": 0.05, "DEF-upper_arm.L.001": 0.05, "DEF-forearm.L": 0.04,
             "DEF-forearm.L.001": 0.06}
    points, faces = [], []
    mesh = bpy.data.meshes.new("Sleeve")
    for name, radius in radii.items():
        bone = rig.data.bones[name]
        head, tail = np.array(bone.head_local), np.array(bone.tail_local)
        axis = (tail - head) / np.linalg.norm(tail - head)
        n1 = np.cross(axis, [0.0, 0.0, 1.0])
        n1 /= np.linalg.norm(n1)
        n2 = np.cross(axis, n1)
        for t in np.linspace(0.0, 1.0, RINGS):
            for k in range(SIDES):
                angle = 2.0 * np.pi * k / SIDES
                points.append(head + t * (tail - head) + radius * (np.cos(angle) * n1 + np.sin(angle) * n2))
    mesh.from_pydata([p.tolist() for p in points], [], faces)
    sleeve = bpy.data.objects.new("Sleeve", mesh)
    bpy.context.scene.collection.objects.link(sleeve)
    per = RINGS * SIDES
    for i, name in enumerate(radii):
        sleeve.vertex_groups.new(name=name).add(list(range(i * per, (i + 1) * per)), 1.0, 'REPLACE')
    sleeve.modifiers.new("Armature", 'ARMATURE').object = rig
    bpy.context.view_layer.objects.active = rig
    found = thickness.limb_radii(rig, rig_cache.rig_of(rig))
    assert set(found) == {"arm.L"}
    np.testing.assert_allclose(found["arm.L"], 0.06, rtol=1e-5)  # the forearm's second half, the thickest


@pytest.mark.parametrize("margin", [0.0, 0.05])
def test_a_box_inside_the_forearm_where_it_was_ends_outside_the_mesh(extension_module_name, margin):
    """A box smaller than the forearm is thick, where its middle was in the pose solved without it (all of it
    inside the mesh, no vertex in it): the paper's solve pushes the bones' centre line just out of it, through the
    forearm's surface; with the mesh's thickness the elbow swings round so the surface comes out of it too."""
    obj, body, owner, rest = arm_scene()
    free = adjusted(obj, rest, 0.0, True, body)
    wrist_free, elbow_free = (free.to_world(free.head(b)) for b in ("hand.L", "forearm.L"))
    box = add_box(obj, 0.5 * (wrist_free + elbow_free), 0.04)
    bpy.context.view_layer.update()
    assert (box_distances(box, arm_vertices(body, owner)) > 0.0).all(), "the set-up: the box inside the forearm"
    paper = adjusted(obj, rest, 0.0, False, body)
    assert (box_distances(box, paper.to_world(chain_joints(obj, paper, "arm.L"))) > 0.0).all()
    paper_in = int((box_distances(box, arm_vertices(body, owner)) == 0.0).sum())
    assert paper_in > 0, "the set-up: the paper's centre line out of the box, the forearm's surface through it"
    after = adjusted(obj, rest, margin, True, body)
    distances = box_distances(box, arm_vertices(body, owner))
    print(f"paper (no mesh): {paper_in} vertices inside; margin {margin}: {int((distances == 0.0).sum())}, "
          f"nearest {distances.min():.4f} m")
    assert (distances > 0.0).all()
    goal = np.array(evaluated(slot(obj, "hand.L").target).matrix_world.translation)
    assert np.linalg.norm(after.to_world(after.head("hand.L")) - goal) < 1e-4


def test_a_limbs_surface_is_its_mesh_where_the_start_pose_puts_it(extension_module_name):
    """limb_surfaces: the arm's vertices (upper arm and forearm, not the torso's) at a posed start, through the
    solve space, are the evaluated (deformed) mesh's own vertices there."""
    thickness = importlib.import_module(f"{extension_module_name}.bridge.reading.limb_thickness")
    rig_cache = importlib.import_module(f"{extension_module_name}.bridge.rig.rig_cache")
    solve_space = importlib.import_module(f"{extension_module_name}.bridge.reading.solve_space")
    pose = importlib.import_module(f"{extension_module_name}.bridge.reading.pose")
    obj, body, owner, _rest = arm_scene()
    obj.location = (0.3, -0.2, 0.1)
    obj.scale = (2.0, 2.0, 2.0)
    for name, angles in (("upper_arm.L", (0.3, 0.2, -0.4)), ("forearm.L", (0.7, 0.0, 0.1))):
        pb = obj.pose.bones[name]
        pb.rotation_mode = 'XYZ'
        pb.rotation_euler = angles
    bpy.context.view_layer.update()
    rig = rig_cache.rig_of(obj)
    snapshot = pose.read_pose_frames(obj, [bpy.context.scene.frame_current])
    to_solve, _heads, _tails, unit = solve_space.solve_space(snapshot, rig.ends)
    surfaces = thickness.limb_surfaces(obj, rig, snapshot.matrices, to_solve)
    assert set(surfaces) == {"arm.L"}  # the trunk has a radius, but no swivel to turn its surface out by
    arm = surfaces["arm.L"]
    world = arm_vertices(body, owner)  # the upper arm's and forearm's, evaluated
    world_matrix = np.array(obj.matrix_world)
    got = (arm.points[0] / unit[0]) @ world_matrix[:3, :3].T + world_matrix[:3, 3]
    assert arm.points.shape == (1, len(world), 3)
    nearest = np.linalg.norm(got[:, None] - world[None], axis=-1).min(axis=1)
    assert nearest.max() < 1e-5, nearest.max()
    # Each rides on its own segment: the upper arm's on the segment before the forearm's.
    chain = rig.model.limbs["arm.L"].bones
    upper = arm.segment == chain.index(obj.data.bones.find("upper_arm.L"))
    assert upper.sum() == RINGS * SIDES and (arm.segment[~upper] == chain.index(obj.data.bones.find("forearm.L"))).all()
    # Every vertex weighted 1 to its bone: all its weight on its own segment (of the chain's, the hand's, the rest's).
    np.testing.assert_array_equal(arm.weights, np.eye(len(chain) + 2)[arm.segment])
