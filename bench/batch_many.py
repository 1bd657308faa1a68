"""Many clips onto one character at pipeline scale: `retarget --source-file` with 1 worker and with N, against
Blender's own way per clip, in the same run.

Clips: 24 cuts of 300-1,000 frames from the CMU clips in tests/data/mocap (their header and a slice of their
frame lines; the MotionBuilder-skeleton clips, 120 fps). Character: the Rigify basic human metarig in a .blend
whose scene runs at 120 fps (so a clip's frames are its own), contacts on the ground, floor 0.

  batch       `python -m fullbody_adjust retarget hero.blend --target Hero --source-file CLIPS --output-dir D
              --jobs J` in a subprocess, timed end to end (worker start, import, retarget, save a .blend per
              clip), with J = 1 and J = N (default: the number of cores). Scaling = (clips/min at N) /
              (clips/min at 1) / N.
  lean bake   per clip, in this process: the clip imported the same way, then bench/batch.py's constraint
              rig (Copy Rotation through helper bones, the root on the planned path, IK on forearms and shins
              aimed at the same targets) baked with nla.bake over only the mapped bones' location and rotation.
              Timed: import + constraints + bake (the batch's time includes import and save too); also
              without the import, against our retarget alone (the row's solve_seconds).

Contact errors: where the plan holds a contact (planted feet), the distance from the wrist or ankle, as
Blender evaluates the saved result frame by frame, to the contact target; ours read back from each clip's output
.blend, the baseline's from its baked rig. Ratios are measured in this one run.

Run: .ci/with-bpy python bench/batch_many.py [--clips 24] [--jobs N] [--baseline-clips 24]   (one JSON object on
stdout). Data credit: mocap.cs.cmu.edu (NSF EIA-0196217), BVH conversion by Bruce Hahne (cgspeed).
"""

import json
import os
from pathlib import Path
import resource
import statistics
import subprocess
import sys
import tempfile
import time

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

import bpy  # noqa: E402
import numpy as np  # noqa: E402

from bench.batch import copy_target, reach_errors, remove_run, run_constraints, stats  # noqa: E402
from bench.command_line import print_report, whole_number_options  # noqa: E402
import fullbody_adjust  # noqa: E402
from fullbody_adjust.bpy_exit import leave  # noqa: E402
from fullbody_adjust.bridge.retarget import clip_import  # noqa: E402
from fullbody_adjust.bridge.rig import mapping  # noqa: E402
from fullbody_adjust.bridge.retarget import run as retarget  # noqa: E402
from tests.helpers.bvh import CMU_CLIPS, MOCAP_DIR, cut_bvh  # noqa: E402

FPS = 120


def make_clips(folder, count):
    """``count`` cuts of 300-1,000 frames, spread over the clips long enough for them (frame line 0, the
    conversion's T-pose, left out)."""
    lengths = {name: int((MOCAP_DIR / name).read_text().split("Frames:", 1)[1].split()[0]) for name in CMU_CLIPS}
    made = []
    for i in range(count):
        want = 300 + (i * 331) % 701
        fitting = [name for name in CMU_CLIPS if lengths[name] - 1 >= min(want, 300)]
        name = fitting[i % len(fitting)]
        frames = min(want, lengths[name] - 1)
        first = 1 + (i * 97) % (lengths[name] - frames)
        path = folder / f"clip{i:02d}_{Path(name).stem}.bvh"
        cut_bvh(MOCAP_DIR / name, path, first, first + frames)
        made.append(path)
    return made


def make_character(path):
    bpy.ops.wm.read_factory_settings(use_empty=True)
    fullbody_adjust.register()
    if "rigify" not in bpy.context.preferences.addons:
        bpy.ops.preferences.addon_enable(module="rigify")
    bpy.context.scene.render.fps, bpy.context.scene.render.fps_base = FPS, 1.0
    bpy.ops.object.armature_basic_human_metarig_add()
    bpy.context.object.name = "Hero"
    bpy.ops.wm.save_as_mainfile(filepath=str(path))


def run_batch(character, clips_dir, out_dir, jobs, report):
    """(wall seconds, CPU seconds of the workers and the command, the batch's report)."""
    cpu = resource.getrusage(resource.RUSAGE_CHILDREN)
    started = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "fullbody_adjust", "retarget", str(character), "--target", "Hero",
                           "--source-file", str(clips_dir), "--output-dir", str(out_dir), "--jobs", str(jobs),
                           "--report", str(report), "--quiet"],
                          cwd=REPO, capture_output=True, text=True)
    seconds = time.perf_counter() - started
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if done.returncode not in (0, 1):
        raise SystemExit(f"batch failed ({done.returncode}): {done.stderr.strip().splitlines()[-1:]}")
    cpu_seconds = (after.ru_utime + after.ru_stime) - (cpu.ru_utime + cpu.ru_stime)
    return seconds, cpu_seconds, json.loads(Path(report).read_text())


def contact_errors(rig, bones, frames, targets, contacts):
    errors = reach_errors(rig, bones, frames, targets)
    return errors[contacts]


def baseline(character, clip, out_blend, row):
    """(seconds of the import, of the lean constraint bake, CPU seconds of both, its contact errors, ours'
    contact errors) for one clip."""
    bpy.ops.wm.open_mainfile(filepath=str(character), load_ui=False)
    target = bpy.data.objects["Hero"]
    started, cpu_started = time.perf_counter(), time.process_time()
    source, _added = clip_import.import_clip(bpy.context, str(clip))
    imported = time.perf_counter() - started
    cpu_imported = time.process_time() - cpu_started
    prepared = retarget.prepare(bpy.context, source, target, row["frame_start"], row["frame_end"],
                                floor=0.0)  # the plan ours solved, on the same frames (not timed)
    plan, frames = prepared.plan, prepared.frames
    hand_foot = [mapping.ensure_map(target).bones(e)[-1] for e in plan.effectors]
    rig = copy_target(target, "lean")
    cpu_started = time.process_time()
    mapped = sorted({prepared.target.names[b] for bones in prepared.target.groups.values() for b in bones})
    seconds = run_constraints(rig, source, prepared, frames, plan.world_targets, plan.effectors, mapped)
    cpu = cpu_imported + time.process_time() - cpu_started
    theirs = contact_errors(rig, hand_foot, frames, plan.world_targets, plan.contacts)
    remove_run(rig)
    bpy.ops.wm.open_mainfile(filepath=str(out_blend), load_ui=False)
    ours = contact_errors(bpy.data.objects["Hero"], hand_foot, frames, plan.world_targets, plan.contacts)
    return imported, seconds, cpu, theirs, ours


def main():
    print_report(measure, whole_number_options(
        __doc__, ("--clips", 24, "clips in the batch"), ("--jobs", os.cpu_count() or 1, "workers of the parallel run"),
        ("--baseline-clips", 24, "clips also run through the lean bake")))


def measure(args):
    with tempfile.TemporaryDirectory(prefix="fba-batch-many-") as work:
        work = Path(work)
        (work / "clips").mkdir()
        clips = make_clips(work / "clips", args.clips)
        character = work / "hero.blend"
        make_character(character)
        runs = {}
        for jobs in (1, args.jobs):
            load = os.getloadavg()[0]
            seconds, cpu, report = run_batch(character, work / "clips", work / f"out{jobs}", jobs,
                                             work / f"r{jobs}.json")
            runs[jobs] = {"seconds": seconds, "cpu_seconds": cpu, "load_before": load,
                          "clips_per_minute": 60.0 * args.clips / seconds, "report": report}
        rows = runs[1]["report"]["rows"]
        per_clip_ours = runs[1]["seconds"] / args.clips
        imports, lean, lean_cpu, theirs, ours = [], [], [], [], []
        for clip, row in zip(clips[:args.baseline_clips], rows):
            imported, seconds, cpu, their_errors, our_errors = baseline(character, clip,
                                                                        work / "out1" / f"{clip.stem}.blend", row)
            imports.append(imported)
            lean.append(seconds)
            lean_cpu.append(cpu)
            theirs.extend(their_errors)
            ours.extend(our_errors)
    lean_rows = rows[:len(lean)]
    lean_clip = statistics.mean(np.add(imports, lean))
    frames = [row["frames"] for row in rows if row["frames"]]
    one, many = runs[1]["clips_per_minute"], runs[args.jobs]["clips_per_minute"]
    return {
        "blender": bpy.app.version_string,
        "cores": os.cpu_count(),
        "clips": args.clips,
        "clip_frames": {"min": min(frames), "max": max(frames), "total": sum(frames)} if frames else None,
        "failed": [row["clip"] for row in rows if row["status"] != "done"],
        "load_average_before": {jobs: run["load_before"] for jobs, run in runs.items()},
        "batch_seconds": {jobs: run["seconds"] for jobs, run in runs.items()},
        "batch_cpu_seconds": {jobs: run["cpu_seconds"] for jobs, run in runs.items()},
        "clips_per_minute": {jobs: run["clips_per_minute"] for jobs, run in runs.items()},
        "parallel_scaling": many / one / args.jobs,
        "ours_seconds_per_clip_1_worker": per_clip_ours,
        "ours_solve_frames_per_second": sum(frames) / sum(row["solve_seconds"] for row in rows if row["frames"]),
        "lean_bake_clips": len(lean),
        "lean_bake_seconds_per_clip": lean_clip,
        "speedup_vs_lean_bake_per_clip_1_worker": lean_clip / per_clip_ours,
        "speedup_vs_lean_bake_per_clip_n_workers": lean_clip / (runs[args.jobs]["seconds"] / args.clips),
        # CPU time (less disturbed on a shared machine): ours counts the workers' start and the command too.
        "lean_bake_cpu_seconds_per_clip": statistics.mean(lean_cpu),
        "ours_cpu_seconds_per_clip_1_worker": runs[1]["cpu_seconds"] / args.clips,
        "speedup_vs_lean_bake_per_clip_cpu": statistics.mean(lean_cpu) / (runs[1]["cpu_seconds"] / args.clips),
        "import_seconds_per_clip": statistics.mean(imports),
        # Without the import both share: our retarget (read, plan, solve, write) against constraints + bake.
        "speedup_vs_lean_bake_after_import": statistics.mean(lean) / statistics.mean(
            row["solve_seconds"] for row in lean_rows),
        "contact_error_ours": stats(ours),
        "contact_error_lean_bake": stats(theirs),
    }


if __name__ == "__main__":
    main()
    leave(0)  # the bpy module's own teardown is unreliable (bpy_exit): the report is out
