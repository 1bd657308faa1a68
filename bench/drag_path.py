"""The interactive bench's scripted drag (bench/interactive.py): where the right hand's target goes on each step,
and what is reported of the update times. No bpy here: the bench's Scene places the targets and its timers
(time_live, time_live_floor, time_blender_ik) measure.

The path, in world space (the rigs face -Y, Z up), three legs of equal step counts:
  out     from the near point (0.8 of the arm's length from the right shoulder, as the near case puts it) to
          2.5 arm lengths in front of the shoulder: within reach at first, then the trunk must bend and the pelvis
          move (as far as the planted feet allow), then beyond reach;
  back    the same way back to the near point;
  across  to 0.7 arm lengths in front of the middle of the shoulders, past a box where the right elbow goes at
          the leg's middle without it.
The other targets stay put: the left hand at its near point, the feet where they stand. Each step is one Live
update; live_update_ms, live_floor_ms (the poses each update showed, replayed: bench/interactive.py) and
blender_ik_ms (Blender's IK on the same path; on the generated rig its IK controls) give p50, p95, p99 and the
worst update (ms), and of each leg's updates (legs), Live's also those of its time in the solver (solver);
rig_evaluations_per_update (a control rig) is the mean over Live's updates; hand_residual the largest
wrist-to-target distance in arm lengths at the start, the far point, back near and at the end.
"""

import numpy as np

LEGS = ("out", "back", "across")
FAR = 2.5  # arm lengths in front of the shoulder at the end of the out leg


def waypoints(scene):
    """(4,3): the near point, the far point, the near point again, the across end."""
    near = scene.goals("near", 0)["hand.R"]
    base = scene.arm_base["R"]
    far = base + FAR * scene.arm_reach["R"] * scene.forward
    middle = 0.5 * (scene.arm_base["L"] + scene.arm_base["R"])
    across = middle + 0.7 * scene.arm_reach["R"] * scene.forward
    return np.array([near, far, near, across])


def positions(points, steps):
    """(steps,3) along the polyline ``points``, each leg taking an equal share of the steps, first and last point
    included."""
    legs = len(points) - 1
    t = np.linspace(0.0, legs, steps)
    leg = np.minimum(np.floor(t).astype(int), legs - 1)
    fraction = (t - leg)[:, None]
    return (1.0 - fraction) * points[leg] + fraction * points[leg + 1]


def checkpoints(steps):
    """{step: name} of the steps where the hand's residual is recorded: the path's ends and the steps nearest
    the far point and the near point it comes back to."""
    return {0: "start", round((steps - 1) / 3): "far", round(2 * (steps - 1) / 3): "back", steps - 1: "end"}


def percentiles(times):
    """p50, p95, p99 and the worst of update times (ms), and how many there were."""
    times = np.asarray(times, dtype=np.float64)
    p50, p95, p99 = np.percentile(times, [50.0, 95.0, 99.0])
    return {"p50": round(float(p50), 3), "p95": round(float(p95), 3), "p99": round(float(p99), 3),
            "worst": round(float(times.max()), 3), "steps": int(times.size)}


def measure(scene, steps, timers, evaluations):
    """The drag's report: {measure: percentiles (+ hand_residual at the checkpoints, rig_evaluations_per_update
    of Live on a control rig)} for each of ``timers`` {name: function(scene, "drag", steps) -> [(total ms, ms
    outside the solver)]}; ``evaluations``: the bench's EvaluationCounter. The floor replays what Live showed:
    it must come after live_update_ms."""
    result = {}
    try:
        start = scene.goals("near", 0)
        scene.drag = [dict(start, **{"hand.R": point}) for point in positions(waypoints(scene), steps)]
        scene.add_obstacle(scene.drag[(5 * (steps - 1)) // 6], side="R")  # the across leg's middle
    except Exception as ex:  # a rig the drag cannot set up: say why, the bench goes on
        return {"error": f"{type(ex).__name__}: {ex}"}
    for name, function in timers.items():
        scene.checkpoints = checkpoints(steps) if name != "live_floor_ms" else {}
        scene.residuals = {}
        try:
            evaluations.count = 0
            times = function(scene, "drag", steps)
            result[name] = percentiles([total for total, _outside in times])
            if name == "live_update_ms":  # what of each update the solver took (the rest: reading, placing, Blender)
                result[name]["solver"] = percentiles([total - outside for total, outside in times])
            result[name]["legs"] = {leg: percentiles([total for total, _outside in part])
                                    for leg, part in zip(LEGS, np.array_split(times, len(LEGS)))}
            if scene.residuals:
                result[name]["hand_residual"] = dict(scene.residuals)
            if evaluations.count and name == "live_update_ms":
                result[name]["rig_evaluations_per_update"] = round(evaluations.count / steps, 2)
        except Exception as ex:
            result[name] = {"error": f"{type(ex).__name__}: {ex}"}
    scene.checkpoints, scene.drag = {}, []
    return result
