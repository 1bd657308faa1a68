"""How retargeting keeps what the performer touched, on every clip in tests/data/mocap.

Each clip is imported with Blender's BVH importer into a 30 fps scene (keys scaled to it, as a user's scene
gets them) and retargeted onto the Rigify basic human metarig scaled 1.2 and 0.85. The climb (01_06) gets a
`Bar` box around where the source's wrists rest while it hangs, and is retargeted with the floor and the bar
as contacts; the other clips with the floor.

The figures come from Blender's own evaluation of the written action (frame_set, pose bones), measured
against the source's contacts as the current package finds them (solver.contacts.detect_contacts), so two
versions of the package are measured the same way:

    .ci/with-bpy python bench/contacts.py run OUT_DIR [--package DIR]   # retarget every case, save the
                                                                        # evaluated bones (DIR: another
                                                                        # checkout's package, e.g. older)
    .ci/with-bpy python bench/contacts.py measure OUT_DIR [OUT_DIR...]  # one JSON object on stdout

Per case and effector: contact frames, contact error (max, p95: a foot, its lowest point to what it stands
on; a hand, its nearest point to the bar's box), sliding p95 over plants, frames below the floor, pops
(frame-to-frame steps of the wrist or ankle faster than the source's, scaled, by 1.5 leg lengths per second).

Per case, naturalness as in bench/fullbody.py's Table 1: the mean joint angle error (radians) against the
source's pose on the same frame (angles between adjacent segments of the trunk, arm and leg chains, and each
chain's first segment against its parent segment; both skeletons have chains of the same lengths), of each
result and of the unadjusted start pose (the source's rotations carried onto the target, before the targets
are reached), over all frames and, on the climb, over the hang (both hands on the bar).
"""

import argparse
import contextlib
import inspect
import json
import os
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]

FPS = 30
SCALES = (1.2, 0.85)
CLIMB = "cmu_01_06_climb_sit_f360-1559.bvh"


def parse():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("mode", choices=("run", "measure"))
    parser.add_argument("dirs", nargs="+", type=Path)
    parser.add_argument("--package", type=Path, help="a directory holding the fullbody_adjust package to run")
    return parser.parse_args()


ARGS = parse()
sys.path.insert(0, str(REPO))
if ARGS.package is not None:
    sys.path.insert(0, str(ARGS.package))

import bpy  # noqa: E402
import numpy as np  # noqa: E402

import fullbody_adjust  # noqa: E402
from fullbody_adjust.bpy_exit import leave  # noqa: E402
from fullbody_adjust.bridge.rig import mapping  # noqa: E402
from fullbody_adjust.bridge.retarget import run as retarget  # noqa: E402
from fullbody_adjust.bridge.reading.pose import read_pose_frames  # noqa: E402
from tests.helpers.bvh import CMU_SCALE, MOCAP_DIR  # noqa: E402
from tests.helpers.climb_bar import add_bar  # noqa: E402


@contextlib.contextmanager
def quiet():
    """Blender's and the importers' chatter to stderr: stdout carries only the JSON."""
    sys.stdout.flush()
    saved = os.dup(1)
    os.dup2(2, 1)
    try:
        yield
    finally:
        sys.stdout.flush()
        os.dup2(saved, 1)
        os.close(saved)


def build(clip, scale):
    """(source, target, frames, bar or None) of one case, in a fresh file."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    if not hasattr(bpy.types.Object, "fullbody_adjust"):  # registered once: classes outlive the file
        fullbody_adjust.register()
    for module in ("io_anim_bvh", "rigify"):
        if module not in bpy.context.preferences.addons:
            bpy.ops.preferences.addon_enable(module=module)
    bpy.context.scene.render.fps = FPS
    bpy.ops.import_anim.bvh(filepath=str(MOCAP_DIR / clip), global_scale=CMU_SCALE, update_scene_fps=False,
                            update_scene_duration=True, use_fps_scale=True)
    source = bpy.context.active_object
    lo, hi = source.animation_data.action.frame_range
    frames = np.arange(int(np.ceil(lo)) + 1, int(hi) + 1, dtype=float)  # the conversion's T-pose left out
    bar = None
    if clip == CLIMB:
        names = [b.name for b in source.data.bones]
        wrists = read_pose_frames(source, frames).heads[:, [names.index("LeftHand"), names.index("RightHand")]]
        bar = add_bar(wrists, FPS)
    bpy.ops.object.armature_basic_human_metarig_add()
    target = bpy.context.active_object
    target.scale = (scale,) * 3
    bpy.context.view_layer.update()
    return source, target, frames, bar


def run(out):
    out.mkdir(parents=True, exist_ok=True)
    new_api = "contact_object" not in inspect.signature(retarget.retarget).parameters
    for clip in sorted(p.name for p in MOCAP_DIR.glob("*.bvh")):
        for scale in SCALES:
            with quiet():
                source, target, frames, bar = build(clip, scale)
                if new_api:
                    contacts = ["ground"] + ([("object", bar)] if bar else [])
                    retarget.retarget(bpy.context, source, target, int(frames[0]), int(frames[-1]), contacts=contacts)
                else:  # one contact kind per run: the bar where there is one
                    retarget.retarget(bpy.context, source, target, int(frames[0]), int(frames[-1]),
                                      contacts="object" if bar else "ground", contact_object=bar)
                snapshot = read_pose_frames(target, frames)
            np.savez(out / f"{clip}_{scale}.npz", heads=snapshot.heads, tails=snapshot.tails)
            print(f"ran {clip} x{scale}", file=sys.stderr)


def _saved_points(rig, heads, tails, effector):
    """A hand's or foot's points (F,P,3) of saved world heads and tails: its joint, then the heads and tails of
    its bone and every bone below it (as Blender evaluated them)."""
    below = rig.descendants(rig.groups[effector][0])
    return np.concatenate([heads[:, below[:1]], heads[:, below], tails[:, below]], axis=1)


def angles_of(rig, heads, tails):
    """(F,A) joint angles of bench/fullbody.py's Table 1 of a rig's world heads and tails (F,J,3)."""
    from fullbody import body_chains, joint_angles
    from fullbody_adjust.solver.retarget import motion as rt
    model, bones = rt.body_model(rig)
    heads, tails = heads[:, bones], tails[:, bones]
    return joint_angles(model, body_chains(model, heads, tails), heads, tails)


def angle_errors(angles, source_angles, hang):
    """Mean joint angle error (radians) against the source's, over all frames and over the hang (None where
    the skeletons' chains differ in length or there is no hang)."""
    if angles.shape != source_angles.shape:
        return {"all": None, "hang": None}
    error = np.abs(angles - source_angles).mean(axis=1)
    return {"all": float(error.mean()), "hang": float(error[hang].mean()) if hang.any() else None}


def measure(dirs):
    from fullbody_adjust.bridge.retarget.read import rig_of
    from fullbody_adjust.solver.retarget import motion as rt
    results = {}
    for clip in sorted(p.name for p in MOCAP_DIR.glob("*.bvh")):
        for scale in SCALES:
            with quiet():
                source, target, frames, bar = build(clip, scale)
                contacts = ["ground"] + ([("object", bar)] if bar else [])
                prepared = retarget.prepare(bpy.context, source, target, int(frames[0]), int(frames[-1]),
                                            contacts=contacts)
            plan, rig = prepared.plan, rig_of(target, mapping.load_map(target))
            names = [b.name for b in target.data.bones]
            order = [names.index(n) for n in rig.names]
            s_heads, s_tails = prepared.source.world_points(prepared.source_pose)
            s_points = {e: rt.effector_points(prepared.source, prepared.source_pose, e) for e in rt.EFFECTORS}
            listed = {e: [f"{c.kind} {c.start}-{c.stop}" for c in plan.contact_list[e]] for e in rt.EFFECTORS}
            case = {"frames": len(frames), "contacts": listed}
            source_angles = angles_of(prepared.source, s_heads, s_tails)
            hang = plan.contacts[:, :2].all(axis=1)  # both hands held on the bar
            start_heads, start_tails = prepared.target.world_points(plan.start_pose)
            case["naturalness"] = {"start_pose": angle_errors(angles_of(rig, start_heads, start_tails),
                                                              source_angles, hang)}
            for d in dirs:
                saved = np.load(d / f"{clip}_{scale}.npz")
                heads, tails = saved["heads"][:, order], saved["tails"][:, order]
                case["naturalness"][d.name] = angle_errors(angles_of(rig, heads, tails), source_angles, hang)
                figures, _ = rt.contact_figures(
                    plan.contact_list, {e: _saved_points(rig, heads, tails, e) for e in rt.EFFECTORS}, s_points,
                    plan.boxes, plan.ground, rt.leg_length(rig), plan.leg_ratio, FPS)
                case[d.name] = {e: {"contact_error_max": f["contact_error"]["max"],
                                    "contact_error_p95": f["contact_error"]["p95"],
                                    "sliding_p95": f["sliding"]["p95"], "frames_below_floor": f["frames_below_floor"],
                                    "deepest_below_floor": f["deepest_below_floor"], "pops": f["pops"],
                                    "largest_step": f["largest_step"]} for e, f in figures.items()}
            results[f"{clip} x{scale}"] = case
            print(f"measured {clip} x{scale}", file=sys.stderr)
    print(json.dumps({"fps": FPS, "scales": SCALES, "cases": results}, indent=1))


if __name__ == "__main__":
    if ARGS.mode == "run":
        run(ARGS.dirs[0])
    else:
        measure(ARGS.dirs)
    leave(0)  # the bpy module's own teardown is unreliable (bpy_exit): the report is out
