"""A 1,000-frame retarget end to end against Blender's own way to the same result.

Scene: the CMU clip 02_06 (bend and pick up, planted feet) imported with Blender's BVH importer; the target is
the Rigify basic human metarig (another skeleton: 29 bones, A-pose, other proportions) scaled 1.2.
Frames 2-1001 (frame 1 is the conversion's T-pose).

  ours         fullbody_adjust.bridge.retarget.run.retarget(): read the source's F-Curves, transfer the
               rotations, plan the targets (scaled trajectories, planted feet held, the body shifted where a
               limb cannot reach), one vectorised adjust_frames over all frames, write a new action.
               Timed end to end.
  constraints  Blender's own way to the same result, end to end: constraints on a copy of the same rig,
               baked. The rotation transfer by Copy Rotation: each mapped target bone copies the world
               rotation of a helper bone that copies its source bone's rotation before its own rest
               orientation (the rest alignment ours applies, W_t = W_s W_s_rest^-1 A W_t_rest), the root by
               Copy Location from an empty on the same root path ours plans; IK constraints on forearm
               (chain 3: forearm, upper arm, shoulder) and shin (chain 2) aim the wrists and ankles at empties
               animated along the same targets ours computed; then a lean bake over the same frames:
               bpy.ops.nla.bake(only_selected, visual_keying, clear_constraints, bake_types={'POSE'},
               channel_types={'LOCATION', 'ROTATION'}) with only the mapped bones selected, so it keys what
               ours keys (the mapped bones' location and rotation), not every channel of every bone
               (channel_types exists in 4.2 through 5.x). Timed: helpers, empties (keyed with foreach_set),
               constraints and the bake; the source is in the scene, as it must be.
  ik_only      A lower bound for Blender: the transferred motion is keyed on the rig beforehand (NOT timed),
               the scene holds nothing else; only the goal empties, the IK constraints and the bake are timed.

All results are measured the same way afterwards: per frame (frame_set), each wrist and ankle (heads of the
hand and foot bones) in world space against its target; median, p99 and max over frames and effectors. Times
are the median, and the best, of --repeat runs in this one process (on a shared machine the best run is the one
least disturbed by other processes); ratios are reference time / ours.

Run: .ci/with-bpy python bench/batch.py [--repeat 3] [--frames 1000]   (prints one JSON object on stdout;
Blender's and the importers' chatter goes to stderr)
"""

import statistics
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

import bpy  # noqa: E402
import numpy as np  # noqa: E402
from mathutils import Matrix  # noqa: E402

import fullbody_adjust  # noqa: E402
from bench.command_line import print_report, whole_number_options  # noqa: E402
from fullbody_adjust.bpy_exit import leave  # noqa: E402
from fullbody_adjust.bridge.writing import keyframes  # noqa: E402
from fullbody_adjust.bridge.rig import mapping  # noqa: E402
from fullbody_adjust.bridge.retarget import run as retarget  # noqa: E402
from fullbody_adjust.solver.retarget import motion as rt  # noqa: E402
from tests.helpers.bvh import CMU_SCALE, MOCAP_DIR  # noqa: E402

CLIP = "cmu_02_06_pickup_f0-1349.bvh"
TARGET_SCALE = 1.2
FIRST_FRAME = 2
LAYERED = "layers" in bpy.types.Action.bl_rna.properties  # 4.4+: F-Curves are made through the action's slot
# IK chains of the reference: the bone carrying the constraint (its tail is the wrist / ankle) and its length.
IK_CHAINS = {"hand.L": ("forearm.L", 3), "hand.R": ("forearm.R", 3), "foot.L": ("shin.L", 2),
             "foot.R": ("shin.R", 2)}


def build_scene():
    bpy.ops.wm.read_factory_settings(use_empty=True)
    fullbody_adjust.register()
    for module in ("io_anim_bvh", "rigify"):
        if module not in bpy.context.preferences.addons:
            bpy.ops.preferences.addon_enable(module=module)
    bpy.ops.import_anim.bvh(filepath=str(MOCAP_DIR / CLIP), global_scale=CMU_SCALE, update_scene_fps=True,
                            update_scene_duration=True)
    source = bpy.context.active_object
    bpy.ops.object.armature_basic_human_metarig_add()
    target = bpy.context.active_object
    target.scale = (TARGET_SCALE,) * 3
    bpy.context.view_layer.update()
    return source, target


def copy_target(target, name):
    copy = target.copy()  # shares the armature data; pose and constraints are the object's own
    copy.name = name
    copy.animation_data_clear()
    bpy.context.scene.collection.objects.link(copy)
    return copy


def select_pose_bones(rig, names):
    """Pose mode on ``rig`` with exactly the bones ``names`` selected."""
    for ob in bpy.context.scene.objects:
        ob.select_set(False)
    rig.select_set(True)
    bpy.context.view_layer.objects.active = rig
    bpy.ops.object.mode_set(mode='POSE')
    wanted = set(names)
    for pose_bone in rig.pose.bones:
        # 5.0 moved bone selection from Bone to PoseBone.
        owner = pose_bone if "select" in pose_bone.bl_rna.properties else pose_bone.bone
        owner.select = pose_bone.name in wanted


def bake(rig, frames, bones):
    """The lean bake: location and rotation channels of ``bones`` only."""
    select_pose_bones(rig, bones)
    bpy.ops.nla.bake(frame_start=int(frames[0]), frame_end=int(frames[-1]), only_selected=True,
                     visual_keying=True, clear_constraints=True, bake_types={'POSE'},
                     channel_types={'LOCATION', 'ROTATION'})
    bpy.ops.object.mode_set(mode='OBJECT')


def keyed_channels(rig):
    """What the rig's action keys: {"bones": how many pose bones, "fcurves": how many F-Curves}."""
    paths = [fc.data_path for fc in keyframes.animating_fcurves(rig)]
    return {"bones": len({p.split('"')[1] for p in paths if p.startswith("pose.bones")}), "fcurves": len(paths)}


def animated_empty(name, frames, locations):
    """An empty keyed along ``locations`` (F,3) at ``frames`` (one foreach_set per F-Curve)."""
    empty = bpy.data.objects.new(name, None)
    bpy.context.scene.collection.objects.link(empty)
    anim = empty.animation_data_create()
    anim.action = bpy.data.actions.new(f"{name}Action")
    for index in range(3):
        if LAYERED:
            fcurve = anim.action.fcurve_ensure_for_datablock(empty, "location", index=index)
        else:
            fcurve = anim.action.fcurves.new("location", index=index)
        fcurve.keyframe_points.add(len(frames))
        fcurve.keyframe_points.foreach_set("co", np.stack([frames, locations[:, index]], 1).ravel())
        fcurve.keyframe_points.foreach_set("interpolation", np.full(len(frames), 1, np.int32))  # LINEAR
        fcurve.update()
    return empty


def add_ik(rig, frames, world_targets, effectors):
    for k, effector in enumerate(effectors):
        bone, chain = IK_CHAINS[effector]
        constraint = rig.pose.bones[bone].constraints.new('IK')
        constraint.target = animated_empty(f"{rig.name}_{effector}_goal", frames, world_targets[:, k])
        constraint.chain_count = chain


def run_ours(source, target, frames):
    start = time.perf_counter()
    outcome = retarget.retarget(bpy.context, source, target, int(frames[0]), int(frames[-1]))
    return time.perf_counter() - start, outcome


def run_constraints(rig, source, prepared, frames, world_targets, effectors, mapped):
    """Blender's way end to end on ``rig``: returns the seconds it took."""
    source_rig, target_rig, plan = prepared.source, prepared.target, prepared.plan
    start = time.perf_counter()
    # Helper bones, one per paired target bone, unparented, resting in the orientation W_s_rest^-1 A W_t_rest:
    # copying the source bone's world rotation before it gives the aligned transfer.
    helper = bpy.data.objects.new(f"{rig.name}_helpers", bpy.data.armatures.new(f"{rig.name}_helpers"))
    bpy.context.scene.collection.objects.link(helper)
    for ob in bpy.context.scene.objects:
        ob.select_set(False)
    bpy.context.view_layer.objects.active = helper
    bpy.ops.object.mode_set(mode='EDIT')
    s_rest = source_rig.rotation @ source_rig.rest[:, :3, :3]
    t_rest = target_rig.rotation @ target_rig.rest[:, :3, :3]
    pairs = [p for p in rt.pair_bones(source_rig, target_rig) if len(p.sources) == 1]
    for pair in pairs:
        bone = helper.data.edit_bones.new(target_rig.names[pair.target])
        bone.tail = (0.0, 0.1, 0.0)
        rest = np.eye(4)
        rest[:3, :3] = s_rest[pair.sources[0]].T @ pair.alignment @ t_rest[pair.target]
        bone.matrix = Matrix(rest)
    bpy.ops.object.mode_set(mode='OBJECT')
    for pair in pairs:
        name = target_rig.names[pair.target]
        follow = helper.pose.bones[name].constraints.new('COPY_ROTATION')
        follow.target, follow.subtarget = source, source_rig.names[pair.sources[0]]
        follow.mix_mode = 'BEFORE'
        follow.target_space = follow.owner_space = 'WORLD'
        copy = rig.pose.bones[name].constraints.new('COPY_ROTATION')
        copy.target, copy.subtarget = helper, name
        copy.target_space = copy.owner_space = 'WORLD'
    root = target_rig.names[target_rig.groups["root"][0]]
    place = rig.pose.bones[root].constraints.new('COPY_LOCATION')
    place.target = animated_empty(f"{rig.name}_root_path", frames,
                                  target_rig.to_world(plan.start_pose[:, target_rig.groups["root"][0], :3, 3]))
    add_ik(rig, frames, world_targets, effectors)
    bake(rig, frames, mapped)
    return time.perf_counter() - start


def run_ik_only(rig, target_rig, base_pose, frames, world_targets, effectors, mapped):
    """IK and bake on ``rig`` already carrying the transferred motion (keyed untimed): the seconds it took."""
    retarget.write_pose(bpy.context, rig, target_rig, base_pose, frames, f"{rig.name}_base")
    start = time.perf_counter()
    add_ik(rig, frames, world_targets, effectors)
    bake(rig, frames, mapped)
    return time.perf_counter() - start


def remove_run(rig):
    """The reference rig and every helper and goal made for it."""
    for ob in [ob for ob in bpy.data.objects if ob.name.startswith(rig.name)]:
        bpy.data.objects.remove(ob)
    bpy.context.view_layer.update()


def unlink(obj):
    """Take ``obj`` out of the scene (kept in the file): the bake evaluates every object in the scene."""
    if bpy.context.view_layer.objects.active == obj:
        bpy.context.view_layer.objects.active = None
    obj.select_set(False)
    bpy.context.scene.collection.objects.unlink(obj)
    bpy.context.view_layer.update()


def reach_errors(rig, bones, frames, world_targets):
    """(F,E) distances from the heads of ``bones`` to the targets, evaluated by Blender frame by frame."""
    scene = bpy.context.scene
    out = np.empty(world_targets.shape[:2])
    for i, frame in enumerate(frames):
        scene.frame_set(int(frame))
        world = np.array(rig.matrix_world)
        for k, bone in enumerate(bones):
            head = world @ np.append(np.array(rig.pose.bones[bone].head), 1.0)
            out[i, k] = np.linalg.norm(head[:3] - world_targets[i, k])
    return out


def bone_directions(rig, bones, frames):
    """World Y axes (F,k,3) of ``bones`` evaluated by Blender frame by frame."""
    scene = bpy.context.scene
    out = np.empty((len(frames), len(bones), 3))
    for i, frame in enumerate(frames):
        scene.frame_set(int(frame))
        world = np.array(rig.matrix_world)[:3, :3]
        for k, bone in enumerate(bones):
            y = world @ np.array(rig.pose.bones[bone].matrix)[:3, 1]
            out[i, k] = y / np.linalg.norm(y)
    return out


def stats(values):
    """Median, p99 and max of ``values``, or None when there are none."""
    values = np.asarray(values, dtype=np.float64)
    if values.size == 0:
        return None
    return {"median": float(np.median(values)), "p99": float(np.percentile(values, 99)), "max": float(values.max())}


def main():
    print_report(measure, whole_number_options(
        __doc__, ("--repeat", 5, "timed runs of each method (median and best reported)"),
        ("--frames", 1000, "frames to retarget, from frame 2")))


def measure(args):
    """Build the scene, time every method and measure the results: the report as a dict."""

    source, target = build_scene()
    frames = np.arange(FIRST_FRAME, FIRST_FRAME + args.frames, dtype=np.float64)
    times = {"ours": [], "constraints": [], "ik_only": []}
    outcome = None
    for _ in range(args.repeat):
        seconds, outcome = run_ours(source, target, frames)
        times["ours"].append(seconds)
    hand_foot = [mapping.load_map(target).bones(e)[-1] for e in outcome.effectors]
    mapped = [bone for _, bone in mapping.load_map(target).items()]
    errors = {"ours": reach_errors(target, hand_foot, frames, outcome.targets)}
    keyed = {"ours": keyed_channels(target)}
    ours_directions = bone_directions(target, mapped, frames)
    prepared = retarget.prepare(bpy.context, source, target, int(frames[0]), int(frames[-1]))
    unlink(target)  # each reference run sees only what it needs

    same_result = None
    for i in range(args.repeat):
        rig = copy_target(target, f"constraints{i}")
        times["constraints"].append(run_constraints(rig, source, prepared, frames, outcome.targets,
                                                    outcome.effectors, mapped))
        if i == 0:
            keyed["constraints"] = keyed_channels(rig)
            errors["constraints"] = reach_errors(rig, hand_foot, frames, outcome.targets)
            turn = np.degrees(np.arccos(np.clip(np.sum(bone_directions(rig, mapped, frames) * ours_directions,
                                                       axis=-1), -1.0, 1.0)))
            same_result = stats(turn)
        remove_run(rig)
    unlink(source)
    for i in range(args.repeat):
        rig = copy_target(target, f"ik_only{i}")
        times["ik_only"].append(run_ik_only(rig, prepared.target, prepared.plan.start_pose, frames,
                                            outcome.targets, outcome.effectors, mapped))
        if i == 0:
            keyed["ik_only"] = keyed_channels(rig)
            errors["ik_only"] = reach_errors(rig, hand_foot, frames, outcome.targets)
        remove_run(rig)

    median = {name: statistics.median(runs) for name, runs in times.items()}
    best = {name: min(runs) for name, runs in times.items()}
    return {
        "blender": bpy.app.version_string,
        "clip": CLIP,
        "frames": int(args.frames),
        "target": f"Rigify basic human metarig, object scale {TARGET_SCALE}",
        "reference_bake": "nla.bake of the mapped bones only (%d of %d), channel_types LOCATION+ROTATION"
                          % (len(mapped), len(target.pose.bones)),
        "keyed_after_run": keyed,
        "leg_ratio": outcome.leg_ratio,
        "source_read_from": outcome.read_from,
        "seconds": median,
        "runs": times,
        "speedup_vs_constraints_bake": median["constraints"] / median["ours"],
        "speedup_vs_ik_only_bake": median["ik_only"] / median["ours"],
        "seconds_best": best,
        "speedup_vs_constraints_bake_best": best["constraints"] / best["ours"],
        "speedup_vs_ik_only_bake_best": best["ik_only"] / best["ours"],
        "ours_fps": args.frames / median["ours"],
        "reach_error": {name: stats(e) for name, e in errors.items()},
        "constraints_vs_ours_bone_direction_deg": same_result,
        "ours_solver_residual": stats(outcome.residuals),
        "contact_frames": {e: int(outcome.contacts[:, k].sum()) for k, e in enumerate(outcome.effectors)},
    }


if __name__ == "__main__":
    main()
    leave(0)  # the bpy module's own teardown is unreliable (bpy_exit): the report is out
