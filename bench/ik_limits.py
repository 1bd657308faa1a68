"""What reading the rig's own joint limits (bridge/reading/ik_limits.py: IK locks and ranges, LOCAL Limit Rotation
constraints, turned into hinge limits by solver/limits/rig_limits.py) adds to one Adjust Pose.

Scene: the Rigify full human metarig (159 bones), targets at the wrists and ankles, the left hand's moved up
and forward so the arm solves. Timed in this one process, --repeat times each, pose reset (not timed) between:

  adjust_plain   one Adjust Pose (bridge.adjustment.adjust_pose, no keys) on the rig as it comes (no settings:
                 the reading finds nothing and the solver takes its default limits)
  read_plain     ik_limits.joint_limits alone on that rig (what every Adjust Pose now pays)
  adjust_set     one Adjust Pose with both forearms IK-locked on X and Z, both shins IK-ranged on X and a LOCAL
                 Limit Rotation on the left upper arm
  read_set       ik_limits.joint_limits alone on that rig (reading and conversion; this includes the default
                 limits it starts from, which the solver no longer computes itself when it is given limits)
  defaults       human.default_limits alone (so read_set - defaults is what the reading adds to a solve)

Prints one JSON object: the median and best time of each (ms) and the ratios read / adjust (medians). A rig
whose limits keep a target out of reach makes the solve itself iterate longer: adjust_set against
adjust_plain shows that, not the reading.

Run: .ci/with-bpy python bench/ik_limits.py [--repeat 20]
"""

import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import bpy  # noqa: E402
import numpy as np  # noqa: E402

import fullbody_adjust  # noqa: E402
from bench.command_line import print_report, whole_number_options  # noqa: E402
from fullbody_adjust.bpy_exit import leave  # noqa: E402
from fullbody_adjust.bridge import adjustment  # noqa: E402
from fullbody_adjust.bridge.reading import ik_limits  # noqa: E402
from fullbody_adjust.bridge.reading import pose  # noqa: E402
from fullbody_adjust.bridge.rig import rig_cache  # noqa: E402
from fullbody_adjust.solver.limits.human import default_limits  # noqa: E402


def build_scene():
    bpy.ops.wm.read_factory_settings(use_empty=True)
    fullbody_adjust.register()
    bpy.ops.preferences.addon_enable(module="rigify")
    bpy.ops.object.armature_human_metarig_add()
    obj = bpy.context.active_object
    bpy.ops.fullbody_adjust.create_targets()
    hand = next(s for s in obj.fullbody_adjust.targets if s.effector == "hand.L").target
    hand.location = hand.location + type(hand.location)((0.0, -0.2, 0.25))
    bpy.context.view_layer.update()
    return obj


def set_limits(obj):
    bones = obj.pose.bones
    for side in "LR":
        bones[f"forearm.{side}"].lock_ik_x = bones[f"forearm.{side}"].lock_ik_z = True
        shin = bones[f"shin.{side}"]
        shin.use_ik_limit_x, shin.ik_min_x, shin.ik_max_x = True, -0.2, 2.4
    con = bones["upper_arm.L"].constraints.new('LIMIT_ROTATION')
    con.owner_space, con.use_limit_x, con.min_x, con.max_x = 'LOCAL', True, -1.0, 1.5


def reset_pose(obj):
    for pb in obj.pose.bones:
        pb.location, pb.rotation_quaternion, pb.rotation_euler = (0, 0, 0), (1, 0, 0, 0), (0, 0, 0)
    bpy.context.view_layer.update()


def time_adjust(obj, repeat):
    times = []
    for _ in range(repeat):
        reset_pose(obj)
        start = time.perf_counter()
        adjustment.adjust_pose(bpy.context, obj, adjustment.Options(insert_keys=False))
        times.append(time.perf_counter() - start)
    reset_pose(obj)
    return times


def time_read(obj, repeat, defaults_only=False):
    snapshot = pose.as_batch(pose.read_pose(obj))  # armature at the origin: world = armature space
    model = rig_cache.rig_of(obj).model
    settings = adjustment.settings_of(obj)
    heads, tails, matrices = snapshot.heads, snapshot.tails, snapshot.pose_matrices
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        if defaults_only:
            default_limits(model, heads, tails, settings.human_limits, matrices[..., :3, 0])
        else:
            ik_limits.joint_limits(obj, model, heads, tails, matrices, settings)
        times.append(time.perf_counter() - start)
    return times


def summary(times):
    return {"median_ms": 1e3 * statistics.median(times), "best_ms": 1e3 * min(times)}


def measure(args):
    obj = build_scene()
    out = {"bones": len(obj.data.bones), "blender": bpy.app.version_string, "numpy": np.__version__}
    out["adjust_plain"] = summary(time_adjust(obj, args.repeat))
    out["read_plain"] = summary(time_read(obj, args.repeat))
    set_limits(obj)
    out["adjust_set"] = summary(time_adjust(obj, args.repeat))
    out["read_set"] = summary(time_read(obj, args.repeat))
    out["defaults"] = summary(time_read(obj, args.repeat, defaults_only=True))
    out["ratio_read_plain_to_adjust"] = out["read_plain"]["median_ms"] / out["adjust_plain"]["median_ms"]
    out["ratio_read_set_to_adjust"] = out["read_set"]["median_ms"] / out["adjust_set"]["median_ms"]
    added = out["read_set"]["median_ms"] - out["defaults"]["median_ms"]
    out["ratio_read_set_less_defaults_to_adjust_plain"] = added / out["adjust_plain"]["median_ms"]
    return out


def main():
    print_report(measure, whole_number_options(__doc__, ("--repeat", 20, "timed runs of each measure")), indent=1)


if __name__ == "__main__":
    main()
    leave(0)  # the bpy module's own teardown is unreliable (bpy_exit): the report is out
