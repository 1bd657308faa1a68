"""Real characters and the rigs users bring: per rig, mapping, Adjust Pose near/far/obstacle and a
retargeted CMU walk, measured from Blender's evaluation of what the product wrote (tests/helpers/rig_measures.py),
never from the solver's own numbers.

Rigs: the corpus of tests/data/rigs/ (imported with Blender's importers at their default settings) and the
generated variants of tests/helpers/real_rigs.py (round trips through Blender's glTF and FBX exporters and
importers, facings, A/T rests, centimetre units, object scales, unnamed joints, soles below the ankle). The product
is used only through its operators and its command line, as a user would:

  mapping    bpy.ops.fullbody_adjust.map_bones(): "ok" or its one line; the bones it gave the hands and feet and
             whether each lies on the character's own side (from the rig's known facing);
  near       Create Targets (a head target, if it makes one, disabled), then the right hand's target moved to
             0.7 of the arm's reach (shoulder to elbow to wrist) in front of the shoulder, the other three where
             they stand; Adjust Pose. keyed_bones, the largest rotation change (degrees, each bone's local
             orientation) of any bone outside the right arm (the upper arm, its descendants and its clavicle),
             which bone, and the right wrist's residual (m);
  far        the right hand's target 1.8 arm lengths in front of the shoulder; Adjust Pose. residual (m), how far
             the target lay beyond the arm alone (m), how much nearer the wrist got (m), and each knee's
             movement along the hips' line (mm);
  obstacle   the near click without an obstacle, to see where the forearm goes; then from the start again with
             a box (edge 0.3 forearm lengths) centred on that forearm's middle; Adjust Pose. Bone heads inside the
             box, evaluated mesh vertices inside (before the click, and in the unobstructed pose: in the way), and of
             those the hand's (weighted most to the hand bone or one below it: the target places the hand);
  retarget   cmu_07_01_walk.bvh imported with Blender's BVH importer into the rig's file (24 fps, keys scaled),
             then `retarget FILE --source Source --target RIG --floor 0` through the command-line function
             (cli.main); exit code, and from the written file: the mesh soles on the source's planted frames (p95
             of |height|, min, in mm; min over all frames), slide p95 (mm), limb directions against the source
             (median degrees), heading error against the source's travel (degrees), pop frames (a bone turning
             more than 30 degrees between frames) against the source's; the product's report's foot contact and
             floor figures against the same measured on the written file.
  fbx_clip   the corpus's FBX clip kenney_run.fbx (Kenney's skeleton, in place) through
             `retarget FILE --target RIG --source-file CLIP --jobs 1`; exit code, pop frames of the written action
             and of the clip itself (as Blender's FBX importer gives it) on the same frames, limb directions
             against the clip (median degrees).
  gltf_walk, gltf_run   the same for two takes of the corpus's glTF move library kaykit_Med_MovementBasic.glb
             (KayKit's skeleton, in place; `--take Walking_A`, `--take Running_A`), the clip's first key on the
             result's first frame.
A row that fails records its error and the bench goes on.

Run: .ci/with-bpy python bench/real_rigs.py [--rigs NAME,NAME] [--skip retarget]   (one JSON object on stdout)
"""

import argparse
import json
import shutil
import sys
import tempfile
import time
import traceback
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

import bpy  # noqa: E402
import numpy as np  # noqa: E402

import fullbody_adjust  # noqa: E402
from bench.command_line import stdout_to_stderr  # noqa: E402
from fullbody_adjust.bpy_exit import leave  # noqa: E402
from fullbody_adjust import cli  # noqa: E402
from tests.helpers import real_rigs  # noqa: E402
from tests.helpers.rig_scenarios import (FPS, WALK, Saved, clip_case, far_case, map_case,  # noqa: E402
                                         near_case, obstacle_case, retarget_case)

CASES = ("mapping", "near", "far", "obstacle", "retarget", "fbx_clip", "gltf_walk", "gltf_run")


def parse():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rigs", help="comma-separated rig names (default: all, see tests/helpers/real_rigs.py)")
    parser.add_argument("--skip", default="", help="comma-separated cases to leave out (e.g. retarget)")
    return parser.parse_args()


def one_line(ex):
    text = " ".join(str(ex).split())
    return f"{type(ex).__name__}: {text}"[:400]


def bench_rig(name, folder, skip):
    row = {}
    started = time.perf_counter()
    try:
        bpy.ops.wm.read_homefile(use_empty=True)
        if not hasattr(bpy.types.Object, "fullbody_adjust"):  # registered once: classes outlive the file
            fullbody_adjust.register()
        saved = Saved(name, folder)
    except Exception as ex:  # noqa: BLE001 - a rig that cannot be built is a row with its error
        traceback.print_exc()
        return {"error": one_line(ex)}
    row["traits"] = {"facing": saved.rig.facing.tolist(), "rest": saved.rig.rest,
                     "metres_per_unit": saved.rig.metres_per_unit,
                     "object_scale": float(np.mean(saved.rig.armature.matrix_world.to_scale())),
                     "bones": len(saved.rig.armature.data.bones), "build_seconds": time.perf_counter() - started}
    cases = {"mapping": map_case, "near": near_case, "far": far_case, "obstacle": obstacle_case,
             "retarget": lambda s: retarget_case(s, folder, cli),
             "fbx_clip": lambda s: clip_case(s, folder, cli),
             "gltf_walk": lambda s: clip_case(s, folder, cli, "kaykit_moves", "Walking_A"),
             "gltf_run": lambda s: clip_case(s, folder, cli, "kaykit_moves", "Running_A")}
    for case, run in cases.items():
        if case in skip:
            continue
        t = time.perf_counter()
        try:
            row[case] = run(saved)
        except Exception as ex:  # noqa: BLE001 - a case that fails records its one line and the bench goes on
            traceback.print_exc()
            row[case] = {"error": one_line(ex)}
        if isinstance(row[case], dict):
            row[case]["seconds"] = round(time.perf_counter() - t, 2)
    return row


def main():
    args = parse()
    names = args.rigs.split(",") if args.rigs else list(real_rigs.ALL)
    skip = set(filter(None, args.skip.split(",")))
    folder = Path(tempfile.mkdtemp(prefix="fba_real_rigs_"))
    report = {"bpy": bpy.app.version_string, "clip": WALK.name, "fps": FPS, "rigs": {}}
    started = time.perf_counter()
    try:
        with stdout_to_stderr():
            for name in names:
                report["rigs"][name] = bench_rig(name, folder, skip)
                print(f"{name}: done", file=sys.stderr)
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    report["seconds"] = time.perf_counter() - started
    print(json.dumps(report, indent=1, default=float))


if __name__ == "__main__":
    main()
    leave(0)
