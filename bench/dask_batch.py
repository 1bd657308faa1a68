"""A clip batch on a Dask cluster of 1 and of 2 workers, against the local pool's --jobs 1 and --jobs 2, in one run.

Clips: 12 cuts of 50-300 frames from the CMU clips in tests/data/mocap (bench/batch_many.py's character: the
Rigify basic human metarig in a .blend at 120 fps, so a clip's frames are its own; contacts on the ground).
Cluster: `python -m distributed.cli.dask_scheduler` and N `python -m distributed.cli.dask_worker ADDRESS
--nthreads 1` of this Python on 127.0.0.1 (tests/helpers/dask_cluster.py), started, with every worker joined,
before the batch is timed (a cluster runs on; its workers start their clip workers within the timed batch, as
--jobs does).

  each run   `python -m fullbody_adjust retarget hero.blend --target Hero --source-file CLIPS --output-dir D
             (--jobs J | --scheduler ADDRESS)` in a subprocess, timed end to end (worker start, import, retarget,
             save a .blend per clip). Scaling = seconds with 1 / seconds with 2.

Every run's report rows are compared with --jobs 1's (but their times): "same_rows" says whether they match.

With --long 1 the clips are bench/batch_many.py's cuts of 300-1,000 frames instead: where a clip's solve, not a
worker's start, is most of its cost.

Run: .ci/with-bpy python bench/dask_batch.py [--clips 12] [--long 0|1]   (one JSON object on stdout; needs
`distributed`).
Data credit: mocap.cs.cmu.edu (NSF EIA-0196217), BVH conversion by Bruce Hahne (cgspeed).
"""

import json
import os
from pathlib import Path
import subprocess
import sys
import tempfile
import time

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

import bpy  # noqa: E402,F401  (the character is made with it)

from bench import batch_many  # noqa: E402
from bench.command_line import print_report, whole_number_options  # noqa: E402
from fullbody_adjust.bpy_exit import leave  # noqa: E402
from tests.helpers.bvh import CMU_CLIPS, MOCAP_DIR, cut_bvh  # noqa: E402
from tests.helpers.dask_cluster import Cluster  # noqa: E402

TIMES = ("seconds", "solve_seconds", "import_seconds", "output")


def make_clips(folder, count):
    """``count`` cuts of 50-300 frames, spread over the clips (frame line 0, the T-pose, left out)."""
    lengths = {name: int((MOCAP_DIR / name).read_text().split("Frames:", 1)[1].split()[0]) for name in CMU_CLIPS}
    made = []
    for i in range(count):
        name = CMU_CLIPS[i % len(CMU_CLIPS)]
        frames = 50 + (i * 97) % 251
        first = 1 + (i * 37) % (lengths[name] - 1 - frames)
        path = folder / f"clip{i:02d}_{Path(name).stem}.bvh"
        cut_bvh(MOCAP_DIR / name, path, first, first + frames)
        made.append(path)
    return made


def run_batch(character, clips, out, report, extra):
    started = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "fullbody_adjust", "retarget", str(character), "--target", "Hero",
                           "--source-file", str(clips), "--output-dir", str(out), "--report", str(report),
                           "--quiet", *extra], cwd=REPO, capture_output=True, text=True)
    seconds = time.perf_counter() - started
    if done.returncode not in (0, 1):
        raise SystemExit(f"batch failed ({done.returncode}): {done.stderr.strip().splitlines()[-1:]}")
    return seconds, json.loads(Path(report).read_text())


def measure(args):
    runs = {}
    with tempfile.TemporaryDirectory(prefix="fba-dask-batch-") as work:
        work = Path(work)
        (work / "clips").mkdir()
        (batch_many.make_clips if args.long else make_clips)(work / "clips", args.clips)
        character = work / "hero.blend"
        batch_many.make_character(character)
        for jobs in (1, 2):
            load = os.getloadavg()[0]
            seconds, report = run_batch(character, work / "clips", work / f"jobs{jobs}", work / f"jobs{jobs}.json",
                                        ["--jobs", str(jobs)])
            runs[f"jobs {jobs}"] = {"seconds": seconds, "load_before": load, "report": report}
        for workers in (1, 2):
            folder = work / f"cluster{workers}"
            folder.mkdir()
            cluster = Cluster(folder, workers)
            try:
                cluster.ready()
                load = os.getloadavg()[0]
                seconds, report = run_batch(character, work / "clips", work / f"dask{workers}",
                                            work / f"dask{workers}.json", ["--scheduler", cluster.address])
            finally:
                cluster.stop()
            runs[f"dask {workers}"] = {"seconds": seconds, "load_before": load, "report": report}

    def plain(report):
        return [{k: v for k, v in row.items() if k not in TIMES} for row in report["rows"]]

    first = plain(runs["jobs 1"]["report"])
    frames = [row["frames"] for row in runs["jobs 1"]["report"]["rows"]]
    return {
        "blender": bpy.app.version_string,
        "cores": os.cpu_count(),
        "clips": args.clips,
        "clip_frames": {"min": min(frames), "max": max(frames), "total": sum(frames)},
        "failed": {name: run["report"]["clips"]["failed"] for name, run in runs.items()},
        "jobs_in_report": {name: run["report"]["jobs"] for name, run in runs.items()},
        "load_average_before": {name: run["load_before"] for name, run in runs.items()},
        "batch_seconds": {name: run["seconds"] for name, run in runs.items()},
        "scaling_jobs_2_over_1": runs["jobs 1"]["seconds"] / runs["jobs 2"]["seconds"],
        "scaling_dask_2_over_1": runs["dask 1"]["seconds"] / runs["dask 2"]["seconds"],
        "same_rows": {name: plain(run["report"]) == first for name, run in runs.items()},
    }


if __name__ == "__main__":
    print_report(measure, whole_number_options(__doc__, ("--clips", 12, "clips in the batch"),
                                               ("--long", 0, "1: cuts of 300-1,000 frames instead of 50-300")))
    leave(0)  # the bpy module's own teardown is unreliable (bpy_exit): the report is out
