"""Fit the default human joint limits on some mocap clips, so other clips can be held out (bench/fullbody.py).

human.HumanLimits says its cones and hinge ranges were chosen to hold every captured pose of the five CMU clips:
the 99.9th percentile of each measured angle, plus a margin. This measures those angles the same way on any
set of clips and turns them into a HumanLimits:

  lumbar    trunk segment 0 vs the direction the solver limits it against (the pelvis' up)
  spine     consecutive trunk segments
  shoulder  upper arm vs clavicle (no clavicle: vs the SC -> shoulder direction)
  elbow     bend between upper arm and forearm (the upper end of the hinge range)
  hip       thigh vs the direction the solver limits it against (the pelvis' down)
  knee      bend between thigh and shin (the upper end of the hinge range)
  neck      consecutive neck segments, the first against the trunk's last segment

The directions the lumbar and hip cones are measured against come from human.default_limits itself, so they
are the solver's. Fitted value = the 99.9th percentile + 5 deg, rounded up to a multiple of 5 deg (this rule
gives the shipped lumbar, spine, shoulder, hip and neck values from the docstring's measurements). Not refitted,
kept from the shipped defaults: the clavicle cone and the hinge twists (both measured between pairs of poses,
not within one pose) and the hinges' lower ends (hyperextension).

Clips: the five CMU clips on the MotionBuilder-style skeleton and the Daz-skeleton walk (tests/data/mocap);
frame 1 of every file is the conversion's T-pose and is left out.

Run alone: .ci/with-bpy python bench/limits_fit.py [clip ...]   (prints one JSON object; default: all clips)
"""

import json
import math
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from fullbody_adjust.solver.body.model import BodyModel  # noqa: E402
from fullbody_adjust.solver.limits.human import HumanLimits, default_limits  # noqa: E402
from tests.helpers.bvh import CMU_CLIPS, CMU_GROUPS, DAZ_GROUPS, MOCAP_DIR, read_bvh, read_cmu  # noqa: E402

DAZ_CLIP = "cmu_daz_02_01_walk.bvh"
DAZ_SCALE = 0.01  # the Daz conversion is in centimetres
ALL_CLIPS = CMU_CLIPS + (DAZ_CLIP,)
PERCENTILE = 99.9
MARGIN_DEG = 5.0
CONES = ("lumbar", "spine", "shoulder", "hip", "neck")
HINGES = ("elbow", "knee")


def load_clip(name):
    """(clip, model) of one shipped clip, in metres."""
    if name == DAZ_CLIP:
        clip = read_bvh(MOCAP_DIR / name, scale=DAZ_SCALE)
        groups = DAZ_GROUPS
    else:
        clip = read_cmu(name)
        groups = CMU_GROUPS
    return clip, BodyModel.from_description(clip.names, clip.parents, groups)


def _angle(a, b):
    cos = np.sum(a * b, axis=-1) / (np.linalg.norm(a, axis=-1) * np.linalg.norm(b, axis=-1))
    return np.arccos(np.clip(cos, -1.0, 1.0))


def measure_angles(model, heads, tails):
    """{limit name: 1-D array of angles (radians)} over poses heads/tails (F,J,3), as the module docstring says."""
    limits = default_limits(model, heads, tails)
    segs = {n: np.diff(limb.joints(heads, tails), axis=1) for n, limb in model.limbs.items()}
    trunk = segs["trunk"]
    out = {"lumbar": [_angle(trunk[:, 0], limits["trunk"].parent_direction)],
           "spine": [_angle(trunk[:, i - 1], trunk[:, i]) for i in range(1, trunk.shape[1])],
           "shoulder": [], "elbow": [], "hip": [], "knee": [], "neck": []}
    for side in ("L", "R"):
        arm = segs[f"arm.{side}"]
        m = arm.shape[1]
        parent = arm[:, m - 3] if m >= 3 else limits[f"arm.{side}"].parent_direction
        out["shoulder"].append(_angle(parent, arm[:, m - 2]))
        out["elbow"].append(_angle(arm[:, m - 2], arm[:, m - 1]))
        leg = segs[f"leg.{side}"]
        out["hip"].append(_angle(limits[f"leg.{side}"].parent_direction, leg[:, 0]))
        out["knee"].append(_angle(leg[:, -2], leg[:, -1]))
    if "head" in segs:
        neck = np.concatenate([trunk[:, -1:], segs["head"]], axis=1)
        out["neck"] = [_angle(neck[:, i - 1], neck[:, i]) for i in range(1, neck.shape[1])]
    return {k: np.concatenate(v) for k, v in out.items() if v}


def captured_angles(clips):
    """measure_angles pooled over every captured frame (the T-pose frame left out) of `clips`."""
    pooled = {}
    for name in clips:
        clip, model = load_clip(name)
        heads, tails = clip.bones(np.arange(1, clip.frame_count))
        for k, v in measure_angles(model, heads, tails).items():
            pooled.setdefault(k, []).append(v)
    return {k: np.concatenate(v) for k, v in pooled.items()}


def _fitted(angle):
    """The 99.9th percentile + the margin, rounded up to a multiple of 5 deg (radians)."""
    deg = math.degrees(float(np.percentile(angle, PERCENTILE))) + MARGIN_DEG
    return math.radians(5.0 * math.ceil(deg / 5.0 - 1e-9))


def fit_limits(clips, shipped=HumanLimits()):
    """(HumanLimits fitted on `clips`, report dict in degrees: measured percentile, fitted, shipped)."""
    angles = captured_angles(clips)
    values, report = {}, {}
    for name in CONES + HINGES:
        if name not in angles:
            continue
        fitted = _fitted(angles[name])
        old = getattr(shipped, name)
        values[name] = (old[0], fitted) if name in HINGES else fitted
        report[name] = {"p99_9_deg": round(math.degrees(float(np.percentile(angles[name], PERCENTILE))), 2),
                        "max_deg": round(math.degrees(float(angles[name].max())), 2),
                        "fitted_deg": round(math.degrees(fitted), 2),
                        "shipped_deg": round(math.degrees(old[1] if name in HINGES else old), 2)}
    return replace(shipped, **values), report


def main():
    clips = tuple(sys.argv[1:]) or ALL_CLIPS
    limits, report = fit_limits(clips)
    print(json.dumps({"clips": list(clips), "rule": f"p{PERCENTILE} + {MARGIN_DEG:g} deg, rounded up to 5 deg",
                      "angles": report, "differs_from_shipped": limits != HumanLimits()}, indent=2))


if __name__ == "__main__":
    main()
