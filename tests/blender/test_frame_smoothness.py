"""Adjust Frames on a target moving smoothly through the arm's reach limit (sample_scenes/reach_near_far.blend:
the right hand's target goes from near, where the arm alone reaches, to far, where the trunk must bend): the
trunk bends a little more on every frame, without a joint giving back what another takes; and the largest
frame-to-frame rotation of any bone against what the target's own motion implies (reach_limit_step)."""

import shutil
from pathlib import Path
from types import SimpleNamespace

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


def turn_degrees(a, b):
    """Degrees of the rotations taking a (...,3,3) to b (...,3,3)."""
    rel = np.einsum("...ki,...kl->...il", a, b)
    return np.degrees(np.arccos(np.clip((np.trace(rel, axis1=-2, axis2=-1) - 1.0) / 2.0, -1.0, 1.0)))


def bone_steps(rotations):
    """(F-1,J) degrees each bone turns from one frame to the next."""
    return turn_degrees(rotations[:-1], rotations[1:])


def largest_step(rotations):
    """(degrees, step index, bone index) of the largest rotation of a bone from one frame to the next."""
    angles = bone_steps(rotations)
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


def two_link_turns(base, a, b, start_dir, targets):
    """Degrees each link of a two-link chain (lengths a, then b, from a fixed `base`) turns between consecutive
    frames to keep its end on `targets` (F,3), the links in the plane of start_dir and the target: the first
    link lies at psi - beta from start_dir, the second at psi + gamma (psi: the target's angle from start_dir;
    beta, gamma: the triangle's angles at the base and at the target, by the law of cosines); a target beyond
    a + b has both links stretched toward it."""
    d = targets - base
    dist = np.linalg.norm(d, axis=1)
    beta = np.arccos(np.clip((a * a + dist * dist - b * b) / (2.0 * a * dist), -1.0, 1.0))
    gamma = np.arccos(np.clip((b * b + dist * dist - a * a) / (2.0 * b * dist), -1.0, 1.0))
    psi = np.arccos(np.clip(d @ start_dir / (dist * np.linalg.norm(start_dir)), -1.0, 1.0))
    return np.degrees(np.abs(np.diff(psi - beta))), np.degrees(np.abs(np.diff(psi + gamma)))


def reach_limit_step(obj, frames):
    """Degrees a bone must turn from one frame to the next to keep the right hand on its target, as the body
    model moves the body, from the target's path and the body's lengths alone (not from a solve). The body
    carries the hand as two two-link chains: while the arm alone reaches, the upper arm and forearm from the
    shoulder; beyond, the trunk leaning about its base (its chord, base to SC) and the arm stretched from the
    SC (its reach plus its base's offset from the SC). Near full stretch a two-link chain turns much faster
    than its end moves (the triangle flattens), which is why the step seen from a whole chain's length
    (implied_step) is no bound here: the SC, held at the trunk's length from its base, can move farther than
    the target. The largest turn of any link, times 2n/(n+1) for the trunk's n joints: a link made of bones
    bent about one axis (the spine's curl) turns its last bone by up to n joint angles while its chord turns by
    about (n+1)/2 of them in an even bend (a bend weighted toward the base turns it less)."""
    slot_r = next(s for s in obj.fullbody_adjust.targets if s.enabled and s.effector == "hand.R")
    targets = []
    for frame in frames:
        bpy.context.scene.frame_set(frame)
        targets.append(np.array(slot_r.target.matrix_world.translation))
    targets = np.array(targets)
    pose = Pose(obj)
    trunk = pose.to_world(chain_joints(obj, pose, "trunk"))
    arm = pose.to_world(chain_joints(obj, pose, "arm.R"))
    turns = two_link_turns(arm[1], np.linalg.norm(arm[2] - arm[1]), np.linalg.norm(arm[3] - arm[2]),
                           arm[2] - arm[1], targets)
    turns += two_link_turns(trunk[0], np.linalg.norm(trunk[-1] - trunk[0]),
                            np.linalg.norm(arm[0] - trunk[-1]) + chain_length(arm), trunk[-1] - trunk[0], targets)
    n = len(trunk) - 1
    return 2.0 * n / (n + 1.0) * float(np.max(turns))


@pytest.fixture(scope="module")
def adjusted_sample(tmp_path_factory):
    """The sample's Character after Adjust Frames over FRAMES (one run for the tests below): its bone names,
    its trunk bones, every bone's rotation on every frame, and the bound measured before the run."""
    path = tmp_path_factory.mktemp("sample") / SAMPLE.name
    shutil.copyfile(SAMPLE, path)
    bpy.ops.wm.open_mainfile(filepath=str(path), load_ui=False)
    obj = bpy.data.objects["Character"]
    bpy.context.view_layer.objects.active = obj
    assert bone_map(obj)  # the sample is mapped
    bound = reach_limit_step(obj, FRAMES)
    assert bpy.ops.fullbody_adjust.adjust_frames(frame_start=FRAMES[0], frame_end=FRAMES[-1]) == {'FINISHED'}
    names = [bone.name for bone in obj.pose.bones]
    return SimpleNamespace(names=names, trunk=[names.index(name) for name in bone_map(obj)["trunk"]],
                           rotations=bone_rotations(obj, FRAMES), bound=bound)


def test_the_trunk_bends_steadily_as_the_target_moves_away(adjusted_sample):
    rotations, trunk = adjusted_sample.rotations, adjusted_sample.trunk
    # Each trunk bone's angle from its first-frame rotation, frame by frame (the target only moves away).
    angles = turn_degrees(rotations[0, trunk], rotations[:, trunk])
    assert angles[-1].min() > 10.0  # the trunk did bend
    assert np.diff(angles, axis=0).min() > -0.1


def test_no_bone_turns_faster_than_the_target_implies(adjusted_sample):
    degrees, step, bone = largest_step(adjusted_sample.rotations)
    bound = adjusted_sample.bound
    print(f"largest bone step {degrees:.2f} deg ({adjusted_sample.names[bone]}, frame {FRAMES[step]}), "
          f"implied {bound:.2f} deg")
    assert degrees <= bound


def test_a_captured_walk_with_a_hand_target_moving_out_of_reach_gains_no_pop():
    """CMU walk: the right hand's target leaves the shoulder forward and down, from within the arm's reach to 1.3
    arm lengths; the adjusted clip turns no bone between two frames by more than the clip itself turns that bone
    there plus twice what the target's own motion implies seen from a whole chain (implied_step). Twice: near
    full stretch a limb turns faster than its chord (reach_limit_step); a bend plane that swings over and back,
    or a bend that jumps between spine joints (ten degrees and more), is what this catches."""
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
    own = bone_steps(bone_rotations(obj, frames))
    implied = implied_step(obj, frames)
    bpy.context.view_layer.objects.active = obj
    assert bpy.ops.fullbody_adjust.adjust_frames(frame_start=frames[0], frame_end=frames[-1]) == {'FINISHED'}
    gained = bone_steps(bone_rotations(obj, frames)) - own
    step, bone = np.unravel_index(np.argmax(gained), gained.shape)
    print(f"largest gain over the clip's own bone step {gained.max():.2f} deg ({obj.pose.bones[int(bone)].name}, "
          f"frame {frames[step]}), implied {implied:.2f} deg")
    assert gained.max() <= 2.0 * implied
