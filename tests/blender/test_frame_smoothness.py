"""Adjust Frames on a target moving smoothly through the arm's reach limit (sample_scenes/reach_near_far.blend:
the right hand's target goes from near, where the arm alone reaches, to far, where the trunk must bend): the
trunk bends a little more on every frame, without a joint giving back what another takes; and the largest
frame-to-frame rotation of any bone against what the target's own motion implies."""

import shutil
from pathlib import Path

import bpy
import numpy as np
import pytest

from .scene_tools import Pose, add_rig, body_axes, bone_map, chain_joints, chain_length, slot

SAMPLE = Path(__file__).resolve().parents[2] / "sample_scenes" / "reach_near_far.blend"
FRAMES = range(1, 49)


def bone_rotations(obj, frames):
    """Armature-space rotations (F,J,3,3) of every pose bone, scale removed, as Blender evaluates each frame."""
    out = []
    for frame in frames:
        bpy.context.scene.frame_set(frame)
        ev = obj.evaluated_get(bpy.context.evaluated_depsgraph_get())
        flat = np.empty(len(ev.pose.bones) * 16, dtype=np.float32)
        ev.pose.bones.foreach_get("matrix", flat)
        m = flat.reshape(-1, 4, 4).transpose(0, 2, 1)[:, :3, :3].astype(np.float64)
        out.append(m / np.linalg.norm(m, axis=1, keepdims=True))
    return np.array(out)


def largest_step(rotations):
    """(degrees, step index, bone index) of the largest rotation of a bone from one frame to the next."""
    rel = np.einsum("fjki,fjkl->fjil", rotations[:-1], rotations[1:])
    angles = np.degrees(np.arccos(np.clip((np.trace(rel, axis1=-2, axis2=-1) - 1.0) / 2.0, -1.0, 1.0)))
    step, bone = np.unravel_index(np.argmax(angles), angles.shape)
    return float(angles.max()), int(step), int(bone)


def implied_step(obj, frames):
    """Degrees a whole chain must turn to carry its end along the target's largest step: the step seen from the
    distance of the shortest chain that follows it (the trunk or the arm, at full stretch)."""
    targets = [s.target for s in obj.fullbody_adjust.targets if s.enabled]
    positions = []
    for frame in frames:
        bpy.context.scene.frame_set(frame)
        positions.append([np.array(t.matrix_world.translation) for t in targets])
    step = float(np.linalg.norm(np.diff(np.array(positions), axis=0), axis=-1).max())
    pose = Pose(obj)
    shortest = min(chain_length(chain_joints(obj, pose, group)) for group in ("trunk", "arm.R"))
    return float(np.degrees(2.0 * np.arcsin(min(1.0, step / (2.0 * shortest)))))


def adjusted_sample(tmp_path):
    """The sample's Character after Adjust Frames over FRAMES, with the implied step measured before it."""
    path = tmp_path / SAMPLE.name
    shutil.copyfile(SAMPLE, path)
    bpy.ops.wm.open_mainfile(filepath=str(path), load_ui=False)
    obj = bpy.data.objects["Character"]
    bpy.context.view_layer.objects.active = obj
    assert bone_map(obj)  # the sample is mapped
    bound = implied_step(obj, FRAMES)
    assert bpy.ops.fullbody_adjust.adjust_frames(frame_start=FRAMES[0], frame_end=FRAMES[-1]) == {'FINISHED'}
    return obj, bound


@pytest.mark.xfail(strict=True, reason="every frame's trunk is solved from the start pose, and FABRIK settles the "
                                       "bend among the spine joints differently from one SC target to the next")
def test_the_trunk_bends_steadily_as_the_target_moves_away(tmp_path):
    obj, _bound = adjusted_sample(tmp_path)
    rotations = bone_rotations(obj, FRAMES)
    names = [bone.name for bone in obj.pose.bones]
    trunk = [names.index(name) for name in bone_map(obj)["trunk"]]
    # Each trunk bone's angle from its first-frame rotation, frame by frame (the target only moves away).
    rel = np.einsum("jki,fjkl->fjil", rotations[0, trunk], rotations[:, trunk])
    angles = np.degrees(np.arccos(np.clip((np.trace(rel, axis1=-2, axis2=-1) - 1.0) / 2.0, -1.0, 1.0)))
    assert angles[-1].min() > 10.0  # the trunk did bend
    assert np.diff(angles, axis=0).min() > -0.1


@pytest.mark.xfail(strict=True, reason="a spine joint that reaches its limit hands its share of the bend to the "
                                       "next joint, which then turns faster than an even bend would")
def test_no_bone_turns_faster_than_the_target_implies(tmp_path):
    obj, bound = adjusted_sample(tmp_path)
    degrees, step, bone = largest_step(bone_rotations(obj, FRAMES))
    print(f"largest bone step {degrees:.2f} deg ({obj.pose.bones[bone].name}, frame {FRAMES[step]}), "
          f"implied {bound:.2f} deg")
    assert degrees <= bound


def test_a_captured_walk_with_a_hand_target_moving_out_of_reach_gains_no_pop():
    """CMU walk: the right hand's target leaves the shoulder forward and down, from within the arm's reach to 1.3
    arm lengths; the adjusted clip turns no bone between two frames by more than the clip itself does plus twice
    what the target's own motion implies. Twice: the trunk's bend still shifts between spine joints by up to that
    (the expected failures above); a bend plane that swings over and back (tens of degrees) is what this catches."""
    obj = add_rig("cmu")
    scene = bpy.context.scene
    frames = range(40, 101)
    bpy.ops.fullbody_adjust.create_targets()
    for target_slot in obj.fullbody_adjust.targets:
        target_slot.enabled = target_slot.effector == "hand.R"
    target = slot(obj, "hand.R").target
    for frame in frames:
        scene.frame_set(frame)
        pose = Pose(obj)
        arm = chain_joints(obj, pose, "arm.R")
        up, _left, forward = body_axes(obj, pose)
        way = (forward - 0.3 * up) / np.linalg.norm(forward - 0.3 * up)
        share = (frame - frames[0]) / (frames[-1] - frames[0])
        target.location = tuple(pose.to_world(arm[-3] + (0.6 + 0.7 * share) * chain_length(arm[-3:]) * way))
        target.keyframe_insert("location", frame=frame)
    own, _step, _bone = largest_step(bone_rotations(obj, frames))
    bound = own + 2.0 * implied_step(obj, frames)
    bpy.context.view_layer.objects.active = obj
    assert bpy.ops.fullbody_adjust.adjust_frames(frame_start=frames[0], frame_end=frames[-1]) == {'FINISHED'}
    degrees, step, bone = largest_step(bone_rotations(obj, frames))
    print(f"largest bone step {degrees:.2f} deg ({obj.pose.bones[bone].name}, frame {frames[step]}), "
          f"the clip's own {own:.2f} deg, bound {bound:.2f} deg")
    assert degrees <= bound
