"""Clips the retargeting was not tuned on, retargeted onto the corpus rigs: per clip and rig,
pop frames (result / clip), slide p95 over the clip's plants (result / clip, mm; and the result's at the clip's
size: divided by the legs' ratio), the mesh soles on planted
frames (p95 of |height|, lowest, mm), limb directions against the clip (median degrees) and the exit code,
measured from Blender's evaluation of the written file (tests/helpers/wild_clips.py says how).

Run: .ci/with-bpy python bench/wild_clips.py [--rigs NAME,NAME] [--clips NAME,NAME[:TAKE]]
     (a table on stderr, one JSON object on stdout, its "totals" summed over the rows: see totals). Clips:
     tests/helpers/wild_clips.CLIPS; kaykit_advanced without a take runs every take.
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

import fullbody_adjust  # noqa: E402
from bench.command_line import stdout_to_stderr  # noqa: E402
from fullbody_adjust import cli  # noqa: E402
from fullbody_adjust.bpy_exit import leave  # noqa: E402
from tests.helpers.rig_scenarios import Saved  # noqa: E402
from tests.helpers.wild_clips import CLIPS, KAYKIT_ADVANCED_TAKES, wild_case  # noqa: E402

RIGS = ("kenney", "quaternius_mannequin_f", "kaykit_manny", "godot_plush", "godot_robot", "gdquest_mannequiny",
        "matt_feet_parented")


def parse():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rigs", help="comma-separated rig names (default: the corpus rigs that map)")
    parser.add_argument("--clips", help="comma-separated clip names, CLIP:TAKE for one take (default: all)")
    return parser.parse_args()


def clip_list(text):
    out = []
    for item in (text.split(",") if text else list(CLIPS)):
        name, _, take = item.partition(":")
        if take:
            out.append((name, take))
        elif name == "kaykit_advanced":
            out.extend((name, t) for t in KAYKIT_ADVANCED_TAKES)
        else:
            out.append((name, None))
    return out


def fmt(value, spec=".1f"):
    return "-" if value is None else format(value, spec)


def line(rig, clip, take, r):
    if "error" in r:
        return f"{rig:22s} {clip + (':' + take if take else ''):38s} ERROR {r['error'][:150]}"
    name = clip + (':' + take if take else '')
    return (f"{rig:22s} {name:38s} pops {r['pop_frames']:3d}/{r['source_pop_frames']:<3d} "
            f"slide {fmt(r['slide_p95_mm']):>6s}/{fmt(r['source_slide_p95_mm']):<6s} "
            f"(at its size {fmt(r['slide_p95_at_source_size_mm']):>6s}) "
            f"soles {fmt(r['sole_planted_p95_mm']):>6s}/{fmt(r['sole_planted_min_mm']):<6s} "
            f"limbs {fmt(r['limb_direction_median_deg'], '.2f'):>5s} exit {r['exit_code']} "
            f"planted {r['planted_frames']}/{2 * r['frames']}")


def totals(rows):
    """Sums over the rows, to compare two runs at a glance: exit codes other than 0 (and rows with an error), pop
    frames (the result's, the clip's, and beyond the clip's row by row), slide p95 (mm, the result's and the clip's)
    and the rows missing the slide goal (5 mm, or the clip's own at its size), planted soles p95 (mm) and the rows
    missing the soles goal (10 mm up, 5 mm down), rows whose limbs are off by more than 5 degrees (median)."""
    done = [r for r in rows if "error" not in r]

    def total(key):
        return sum(r[key] for r in done if r.get(key) is not None)

    slid = [r for r in done if r.get("slide_p95_mm") is not None]
    soled = [r for r in done if r.get("sole_planted_p95_mm") is not None]
    return {
        "rows": len(rows), "errors": len(rows) - len(done),
        "exit_not_0": sum(1 for r in done if r["exit_code"] != 0),
        "pop_frames": total("pop_frames"), "source_pop_frames": total("source_pop_frames"),
        "pop_frames_beyond_source": sum(max(0, r["pop_frames"] - r["source_pop_frames"]) for r in done),
        "slide_p95_mm": round(total("slide_p95_mm"), 1), "source_slide_p95_mm": round(total("source_slide_p95_mm"), 1),
        "slide_missed": sum(1 for r in slid if r["slide_p95_mm"] >= 5.0
                            and r["slide_p95_at_source_size_mm"] > r["source_slide_p95_mm"]),
        "sole_planted_p95_mm": round(total("sole_planted_p95_mm"), 1),
        "soles_missed": sum(1 for r in soled if r["sole_planted_p95_mm"] > 10.0 or r["sole_planted_min_mm"] < -5.0),
        "limbs_missed": sum(1 for r in done if (r.get("limb_direction_median_deg") or 0.0) > 5.0),
    }


def main():
    args = parse()
    rigs = args.rigs.split(",") if args.rigs else list(RIGS)
    clips = clip_list(args.clips)
    folder = Path(tempfile.mkdtemp(prefix="fba_wild_clips_"))
    report = {"bpy": bpy.app.version_string, "rows": []}
    started = time.perf_counter()
    try:
        with stdout_to_stderr():
            for rig in rigs:
                bpy.ops.wm.read_homefile(use_empty=True)
                if not hasattr(bpy.types.Object, "fullbody_adjust"):
                    fullbody_adjust.register()
                saved = Saved(rig, folder)
                for clip, take in clips:
                    t = time.perf_counter()
                    try:
                        r = wild_case(saved, folder, cli, clip, take)
                    except Exception as ex:  # noqa: BLE001 - a case that fails is a row with its error
                        traceback.print_exc()
                        r = {"error": f"{type(ex).__name__}: {' '.join(str(ex).split())}"[:400]}
                    r.update(rig=rig, clip=clip, take=take, seconds=round(time.perf_counter() - t, 1))
                    report["rows"].append(r)
                    print("ROW " + line(rig, clip, take, r), file=sys.stderr, flush=True)
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    report["seconds"] = time.perf_counter() - started
    report["totals"] = totals(report["rows"])
    print("TOTALS " + json.dumps(report["totals"]), file=sys.stderr)
    print(json.dumps(report, indent=1, default=float))


if __name__ == "__main__":
    main()
    leave(0)
