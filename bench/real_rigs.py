"""Real characters and the rigs users bring (issue 27): per rig, mapping, Adjust Pose near/far/obstacle and a
retargeted CMU walk, measured from Blender's evaluation of what the product wrote (tests/helpers/rig_measures.py),
never from the solver's own numbers.

Rigs: the corpus of tests/data/rigs/ (imported with Blender's importers at their default settings) and the
generated variants of tests/helpers/real_rigs.py (round trips through Blender's glTF and FBX exporters and
importers, facings, A/T rests, centimetre units, object scales, unnamed joints, soles below the ankle). The product
is used only through its operators and its command line, as a user would:

  mapping    bpy.ops.fullbody_adjust.map_bones(): "ok" or its one line; the bones it gave the hands and feet and
             whether each lies on the character's own side (from the rig's known facing);
  near       Create Targets, then the right hand's target moved to 0.7 of the arm's reach (shoulder to elbow to
             wrist) in front of the shoulder, the other three where they stand; Adjust Pose. keyed_bones, the
             largest rotation change (degrees, each bone's local orientation) of any bone outside the right arm
             (the upper arm, its descendants and its clavicle), which bone, and the right wrist's residual (m);
  far        the right hand's target 1.8 arm lengths in front of the shoulder; Adjust Pose. residual (m), how far
             the target lay beyond the arm alone (m), how much nearer the wrist got (m), and each knee's
             movement along the hips' line (mm);
  obstacle   the near target with a box (edge 0.3 forearm lengths) 40% of the way from the target back towards
             the elbow; Adjust Pose. Bone heads inside the box, evaluated mesh vertices inside (and before);
  retarget   cmu_07_01_walk.bvh imported with Blender's BVH importer into the rig's file (24 fps, keys scaled),
             then `retarget FILE --source Source --target RIG --floor 0` through the command-line function
             (cli.main); exit code, and from the written file: the mesh soles on the source's planted frames (p95
             of |height|, min, in mm; min over all frames), slide p95 (mm), limb directions against the source
             (median degrees), heading error against the source's travel (degrees), pop frames (a bone turning
             more than 30 degrees between frames) against the source's; and what the product's report says.
A row that fails records its error and the bench goes on.

Run: .ci/with-bpy python bench/real_rigs.py [--rigs NAME,NAME] [--skip retarget]   (one JSON object on stdout)
"""

import argparse
import importlib
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
from tests.helpers import real_rigs, rig_measures as rm  # noqa: E402
from tests.helpers.bvh import CMU_SCALE, MOCAP_DIR  # noqa: E402

WALK = MOCAP_DIR / "cmu_07_01_walk.bvh"
FPS = 24
FIRST_FRAME = 2  # frame 1 is the BVH conversion's T-pose
CMU_JOINTS = real_rigs._side_joints("Hips", real_rigs._lr("Left", "Right", {
    "shoulder": "{s}Arm", "elbow": "{s}ForeArm", "wrist": "{s}Hand", "hip": "{s}UpLeg", "knee": "{s}Leg",
    "ankle": "{s}Foot", "ball": "{s}ToeBase"}))
CASES = ("mapping", "near", "far", "obstacle", "retarget")


def parse():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rigs", help="comma-separated rig names (default: all, see tests/helpers/real_rigs.py)")
    parser.add_argument("--skip", default="", help="comma-separated cases to leave out (e.g. retarget)")
    return parser.parse_args()


def one_line(ex):
    text = " ".join(str(ex).split())
    return f"{type(ex).__name__}: {text}"[:400]


def fresh():
    bpy.ops.wm.read_homefile(use_empty=True)
    if not hasattr(bpy.types.Object, "fullbody_adjust"):  # registered once: classes outlive the file
        fullbody_adjust.register()


def reopen(path):
    bpy.ops.wm.open_mainfile(filepath=str(path), load_ui=False)


class Saved:
    """A rig built once and saved, reopened for every case (each case starts from the same file)."""

    def __init__(self, name, folder):
        fresh()
        rig = real_rigs.load(name)
        self.name, self.rig = name, rig
        self.armature_name = rig.armature.name
        self.mesh_names = [m.name for m in rig.meshes]
        self.path = folder / f"{name}.blend"
        bpy.ops.wm.save_as_mainfile(filepath=str(self.path))

    def open(self):
        reopen(self.path)
        rig = self.rig
        rig.armature = bpy.data.objects[self.armature_name]
        rig.meshes = [bpy.data.objects[n] for n in self.mesh_names]
        bpy.context.view_layer.objects.active = rig.armature
        rig.armature.select_set(True)
        return rig


def metres(rig, value):
    return float(value) * rig.metres_per_unit


def mapped(obj):
    groups = {}
    for item in obj.fullbody_adjust.bone_map:
        groups.setdefault(item.group, []).append(item.bone)
    return groups


def joint(rig, role):
    """World head of the rig's known joint ``role`` (None when it has none)."""
    bone = rig.joints.get(role)
    return None if bone is None else rm.world_heads(rig.armature, [bone])[0]


def wrist_of(rig, side="R"):
    """The wrist: the known joint, else the head of the bone the product mapped to the hand (rigs without one)."""
    w = joint(rig, f"wrist.{side}")
    if w is None:
        w = rm.world_heads(rig.armature, [mapped(rig.armature)[f"hand.{side}"][-1]])[0]
    return w


def arm_of(rig, side="R"):
    shoulder, elbow, wrist = joint(rig, f"shoulder.{side}"), joint(rig, f"elbow.{side}"), wrist_of(rig, side)
    return shoulder, elbow, wrist, float(np.linalg.norm(elbow - shoulder) + np.linalg.norm(wrist - elbow))


def right_arm_bones(rig):
    """The upper arm, every bone below it, and its parent when that lies off the middle on the right (a
    clavicle)."""
    arm = rig.armature
    upper = arm.data.bones[rig.joints["shoulder.R"]]
    bones = {upper.name} | {b.name for b in upper.children_recursive}
    if upper.parent is not None:
        hips = joint(rig, "hips")
        lateral = float((rm.world_heads(arm, [upper.parent.name])[0] - hips) @ rig.left)
        if lateral < -0.02 * float(np.linalg.norm(joint(rig, "shoulder.R") - joint(rig, "shoulder.L"))) - 1e-9:
            bones.add(upper.parent.name)
    return bones


def place_target(rig, effector, position):
    slot = next(s for s in rig.armature.fullbody_adjust.targets if s.effector == effector)
    matrix = slot.target.matrix_world.copy()
    matrix.translation = tuple(float(x) for x in position)
    slot.target.matrix_world = matrix
    bpy.context.view_layer.update()


def near_target(rig):
    shoulder, _, wrist, reach = arm_of(rig)
    down = -rm.UP
    direction = 0.6 * rig.facing + 0.5 * down - 0.4 * rig.left  # in front, down and out to the right
    return shoulder + 0.7 * reach * direction / np.linalg.norm(direction)


def map_case(saved):
    rig = saved.open()
    bpy.ops.fullbody_adjust.map_bones()
    groups = mapped(rig.armature)
    hips = joint(rig, "hips")
    sides = {}
    for group in ("hand.L", "hand.R", "foot.L", "foot.R", "arm.L", "arm.R", "leg.L", "leg.R"):
        bones = groups.get(group, [])
        lateral = [float((h - hips) @ rig.left) for h in rm.world_heads(rig.armature, bones)] if bones else []
        want = 1.0 if group.endswith(".L") else -1.0
        sides[group] = bool(lateral) and all(want * x > 0 for x in lateral)
    return {"mapping": "ok", "groups": {g: groups.get(g) for g in ("hand.L", "hand.R", "foot.L", "foot.R")},
            "sides_right": all(sides.values()), "wrong_side": sorted(g for g, ok in sides.items() if not ok)}


def adjust(rig, setup):
    """Create Targets, ``setup(rig)`` (moves targets, adds obstacles), Adjust Pose; returns (rotation changes,
    keyed bones, the operator's report line)."""
    bpy.ops.fullbody_adjust.create_targets()
    setup(rig)
    before_rot, before_keys = rm.local_rotations(rig.armature), rm.keys_snapshot(rig.armature)
    bpy.ops.fullbody_adjust.adjust_pose()
    return rm.rotation_changes(before_rot, rm.local_rotations(rig.armature)), \
        rm.keyed_bones(before_keys, rm.keys_snapshot(rig.armature))


def near_case(saved):
    rig = saved.open()
    target = near_target(rig)
    changes, keyed = adjust(rig, lambda r: place_target(r, "hand.R", target))
    arm = right_arm_bones(rig)
    outside = {b: d for b, d in changes.items() if b not in arm}
    worst = max(outside, key=outside.get)
    return {"keyed_bones": len(keyed), "keyed_outside_right_arm": sorted(set(keyed) - arm),
            "max_rotation_outside_right_arm_deg": outside[worst], "that_bone": worst,
            "residual_m": metres(rig, np.linalg.norm(wrist_of(rig) - target))}


def far_case(saved):
    rig = saved.open()
    shoulder, _, wrist, reach = arm_of(rig)
    target = shoulder + 1.8 * reach * rig.facing + 0.1 * reach * rm.UP
    knees = [rig.joints["knee.L"], rig.joints["knee.R"]]
    hips_line = joint(rig, "hip.L") - joint(rig, "hip.R")
    hips_line /= np.linalg.norm(hips_line)
    knees_before = rm.world_heads(rig.armature, knees)
    adjust(rig, lambda r: place_target(r, "hand.R", target))
    knees_after = rm.world_heads(rig.armature, knees)
    sideways = (knees_after - knees_before) @ hips_line
    return {"residual_m": metres(rig, np.linalg.norm(wrist_of(rig) - target)),
            "beyond_arm_m": metres(rig, np.linalg.norm(target - shoulder) - reach),
            "wrist_gained_m": metres(rig, np.linalg.norm(target - wrist) - np.linalg.norm(wrist_of(rig) - target)),
            "knee_sideways_mm": {"L": metres(rig, sideways[0]) * 1e3, "R": metres(rig, sideways[1]) * 1e3}}


def obstacle_case(saved):
    rig = saved.open()
    target = near_target(rig)
    _, elbow, wrist, _ = arm_of(rig)
    forearm = float(np.linalg.norm(wrist - elbow))
    centre = target + 0.4 * (elbow - wrist)
    bpy.ops.mesh.primitive_cube_add(size=0.3 * forearm, location=tuple(centre))
    box = bpy.context.active_object
    box.name = "Obstacle"
    bpy.context.view_layer.objects.active = rig.armature
    lo, hi = rm.box_bounds(box)
    before = rm.vertices_inside(rm.mesh_vertices(rig.meshes), lo, hi)
    adjust(rig, lambda r: place_target(r, "hand.R", target))
    heads = rm.world_heads(rig.armature)
    return {"joints_inside": rm.vertices_inside(heads, lo, hi),
            "mesh_vertices_inside": rm.vertices_inside(rm.mesh_vertices(rig.meshes), lo, hi),
            "mesh_vertices_inside_before": before, "residual_m": metres(rig, np.linalg.norm(wrist_of(rig) - target))}


def cli_module():
    return importlib.import_module("fullbody_adjust.cli")


def retarget_case(saved, folder):
    rig = saved.open()
    scene = bpy.context.scene
    scene.render.fps = FPS
    if "io_anim_bvh" not in bpy.context.preferences.addons:
        bpy.ops.preferences.addon_enable(module="io_anim_bvh")
    bpy.ops.import_anim.bvh(filepath=str(WALK), global_scale=CMU_SCALE / rig.metres_per_unit,
                            update_scene_fps=False, update_scene_duration=True, use_fps_scale=True)
    source = bpy.context.active_object
    source.name = "Source"
    last = int(np.floor(source.animation_data.action.frame_range[1]))
    path_in, path_out, report_path = (folder / f"{saved.name}_walk{ext}" for ext in (".blend", "_out.blend", ".json"))
    bpy.ops.wm.save_as_mainfile(filepath=str(path_in))
    argv = ["retarget", str(path_in), "--source", "Source", "--target", saved.armature_name, "--frame-start",
            str(FIRST_FRAME), "--frame-end", str(last), "--floor", "0", "--output", str(path_out), "--report",
            str(report_path), "--quiet"]
    code = cli_module().main(argv)
    out = {"exit_code": code}
    if not path_out.exists():
        out["error"] = "no output written"
        return out
    reopen(path_out)
    report = json.loads(report_path.read_text()) if report_path.exists() else {}
    out.update(measure_walk(saved, last, report.get("contacts")))
    return out


def assign_new_action(armature):
    anim = armature.animation_data
    if anim is not None and anim.action is not None and (bpy.app.version < (4, 4, 0) or anim.action_slot):
        return anim.action.name
    raise RuntimeError("the target has no action after the retarget")


def report_agreement(rig, contacts, frames, soles):
    """The report's foot contact and floor figures beside the same figures measured on the written file (mm):
    per foot, its largest contact error against the largest |sole height| over the frames the report lists as
    that foot's contacts, and its deepest point below the floor against the lowest sole over all frames."""
    out = {}
    scale = rig.metres_per_unit * 1e3
    for side in ("L", "R"):
        figures = (contacts or {}).get("effectors", {}).get(f"foot.{side}")
        if figures is None or side not in soles:
            continue
        listed = np.zeros(len(frames), dtype=bool)
        for c in figures["contacts"]:
            listed |= (frames >= c["frame_start"]) & (frames <= c["frame_end"])
        sole = soles[side] * 1e3
        measured_error = float(np.abs(sole[listed]).max()) if listed.any() else None
        reported_error = figures["contact_error"]["max"]
        out[f"foot.{side}"] = {
            "contact_error_max": {"report": None if reported_error is None else reported_error * scale,
                                  "measured": measured_error},
            "deepest_below_floor": {"report": figures["deepest_below_floor"] * scale,
                                    "measured": max(0.0, -float(sole.min()))},
            "frames_below_floor": {"report": figures["frames_below_floor"], "measured": int((sole < -1.0).sum())}}
    worst = [abs(v["report"] - v["measured"]) for foot in out.values() for k, v in foot.items()
             if k != "frames_below_floor" and v["report"] is not None and v["measured"] is not None]
    return {"largest_disagreement_mm": max(worst) if worst else None, "feet": out}


def measure_walk(saved, last, contacts):
    rig = saved.rig
    rig.armature = bpy.data.objects[saved.armature_name]
    rig.meshes = [bpy.data.objects[n] for n in saved.mesh_names]
    source = bpy.data.objects["Source"]
    action = assign_new_action(rig.armature)
    frames = np.arange(FIRST_FRAME, last + 1)
    roles = [r for r, b in rig.joints.items() if b]
    source_roles = [r for r in roles if CMU_JOINTS.get(r)]
    (heads, source_heads), (rots, source_rots), verts = rm.sample(
        frames, [(rig.armature, [rig.joints[r] for r in roles]), (source, [CMU_JOINTS[r] for r in source_roles])],
        rig.meshes)
    track = {r: heads[:, i] for i, r in enumerate(roles)}
    source_track = {r: source_heads[:, i] for i, r in enumerate(source_roles)}
    mpu = rig.metres_per_unit
    soles_planted, soles_all, slide, soles = [], [], [], {}
    for side in ("L", "R"):
        planted, which = rm.plants(source_track[f"ankle.{side}"], source_track.get(f"ball.{side}"), FPS, 1.0)
        foot_bones = {rig.joints[f"ankle.{side}"], rig.joints.get(f"ball.{side}")} - {None}
        masks = rm.foot_vertex_masks(rig.meshes, foot_bones)
        mask = np.concatenate(masks) if masks else None
        if mask is not None and mask.any():
            sole = np.array([v[mask, 2].min() for v in verts]) * mpu
            soles_planted.append(sole[planted])
            soles_all.append(sole)
            soles[side] = sole
        slide.append(rm.slides(planted, which, {"ankle": track[f"ankle.{side}"], "ball": track.get(f"ball.{side}")})
                     * mpu)
    planted_soles = np.concatenate(soles_planted) if soles_planted else np.zeros(0)
    all_soles = np.concatenate(soles_all) if soles_all else np.zeros(0)
    slide = np.concatenate(slide)
    angles = rm.limb_direction_angles(track, source_track)
    source_facing = rm.body_frames(source_track["hip.L"], source_track["hip.R"])[:, 1].mean(axis=0)
    heading = rm.heading_error(track["hips"], rig.facing, source_track["hips"], source_facing)
    limbs = [i for i, r in enumerate(roles) if r.split(".")[0] in rm.POP_ROLES]
    source_limbs = [i for i, r in enumerate(source_roles) if r.split(".")[0] in rm.POP_ROLES]
    rots, source_rots = rots[:, limbs], source_rots[:, source_limbs]
    mm = 1e3
    return {
        "action": action, "frames": len(frames), "planted_frames": int(planted_soles.size),
        "sole_planted_p95_mm": float(np.percentile(np.abs(planted_soles), 95)) * mm if planted_soles.size else None,
        "sole_planted_min_mm": float(planted_soles.min()) * mm if planted_soles.size else None,
        "sole_min_mm": float(all_soles.min()) * mm if all_soles.size else None,
        "slide_p95_mm": float(np.percentile(slide, 95)) * mm if slide.size else None,
        "limb_direction_median_deg": float(np.median(angles)) if angles.size else None,
        "heading_error_deg": heading,
        "pop_frames": len(rm.pop_frames(rots)), "source_pop_frames": len(rm.pop_frames(source_rots)),
        "largest_step_deg": rm.largest_step(rots), "source_largest_step_deg": rm.largest_step(source_rots),
        "report_vs_measured": report_agreement(rig, contacts, frames, soles),
    }


def bench_rig(name, folder, skip):
    row = {}
    started = time.perf_counter()
    try:
        saved = Saved(name, folder)
    except Exception as ex:  # noqa: BLE001 - a rig that cannot be built is a row with its error
        traceback.print_exc()
        return {"error": one_line(ex)}
    row["traits"] = {"facing": saved.rig.facing.tolist(), "rest": saved.rig.rest,
                     "metres_per_unit": saved.rig.metres_per_unit,
                     "object_scale": float(np.mean(saved.rig.armature.matrix_world.to_scale())),
                     "bones": len(saved.rig.armature.data.bones), "build_seconds": time.perf_counter() - started}
    cases = {"mapping": map_case, "near": near_case, "far": far_case, "obstacle": obstacle_case,
             "retarget": lambda s: retarget_case(s, folder)}
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
