"""The scenarios of the characters users bring, on a real rig, run through the product's public entry points only
(its operators and its command-line function) and measured with rig_measures from Blender's evaluation of what it
wrote; shared by tests/blender/test_real_rigs.py and bench/real_rigs.py (whose docstring describes each scenario).

  map_case, near_case, far_case, obstacle_case (Saved) -> dict of figures
  retarget_case(Saved, folder, cli) -> dict of figures (cli: the product's cli module, whose main(argv) is the
                                       command line)
A rig is built once (`Saved`) and reopened from its .blend for every scenario.
"""

import contextlib
import io
import json

import bpy
import numpy as np

from tests.helpers import real_rigs, rig_measures as rm
from fullbody_adjust.solver.body.joint_ends import joint_ends
from tests.helpers.blender_data import bone_map, evaluated
from tests.helpers.bvh import CMU_SCALE, MOCAP_DIR

WALK = MOCAP_DIR / "cmu_07_01_walk.bvh"
FPS = 24
FIRST_FRAME = 2  # frame 1 is the BVH conversion's T-pose
CMU_JOINTS = real_rigs.side_joints("Hips", real_rigs.left_right("Left", "Right", {
    "shoulder": "{s}Arm", "elbow": "{s}ForeArm", "wrist": "{s}Hand", "hip": "{s}UpLeg", "knee": "{s}Leg",
    "ankle": "{s}Foot", "ball": "{s}ToeBase"}))


def reopen(path):
    bpy.ops.wm.open_mainfile(filepath=str(path), load_ui=False)


class Saved:
    """A rig built once and saved, reopened for every case (each case starts from the same file)."""

    def __init__(self, name, folder):
        bpy.ops.wm.read_homefile(use_empty=True)
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


def joint(rig, role):
    """World head of the rig's known joint ``role`` (None when it has none)."""
    bone = rig.joints.get(role)
    return None if bone is None else rm.world_heads(rig.armature, [bone])[0]


def wrist_of(rig, side="R"):
    """The wrist: the known joint, else the head of the bone the product mapped to the hand, else (an arm mapped
    with no hand bone) where the arm's last bone ends (joint_ends: at rest, in the bone's frame) as Blender
    evaluates that bone now."""
    w = joint(rig, f"wrist.{side}")
    if w is None:
        groups = bone_map(rig.armature)
        hand = [bone for bone in groups.get(f"hand.{side}", []) if bone]
        w = rm.world_heads(rig.armature, hand)[0] if hand else bone_end(rig.armature, groups[f"arm.{side}"][-1])
    return w


def bone_end(armature, name):
    """World point where bone ``name`` ends as a joint (solver.joint_ends at rest), carried by its evaluated pose."""
    bones = armature.data.bones
    parents = [bones.find(b.parent.name) if b.parent else -1 for b in bones]
    rest = np.array([b.matrix_local for b in bones], dtype=np.float64)
    ends = joint_ends(parents, rest, np.array([b.tail_local for b in bones], dtype=np.float64))
    ev = evaluated(armature)
    posed = np.array(ev.matrix_world, dtype=np.float64) @ np.array(ev.pose.bones[name].matrix, dtype=np.float64)
    return posed[:3, :3] @ ends[bones.find(name)] + posed[:3, 3]


def arm_of(rig, side="R"):
    """(shoulder, elbow, wrist, reach: shoulder to elbow to wrist) in the world."""
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
    groups = bone_map(rig.armature)
    hips = joint(rig, "hips")
    sides = {}
    for group in ("hand.L", "hand.R", "foot.L", "foot.R", "arm.L", "arm.R", "leg.L", "leg.R"):
        bones = [bone for bone in groups.get(group, []) if bone]
        points = rm.world_heads(rig.armature, bones) if bones else []
        if group.startswith("hand") and not bones and groups.get(group):  # a hand row with no bone: the wrist
            points = [bone_end(rig.armature, groups[f"arm.{group[-1]}"][-1])]
        lateral = [float((h - hips) @ rig.left) for h in points]
        want = 1.0 if group.endswith(".L") else -1.0
        sides[group] = bool(lateral) and all(want * x > 0 for x in lateral)
    return {"mapping": "ok", "groups": groups,
            "sides_right": all(sides.values()), "wrong_side": sorted(g for g, ok in sides.items() if not ok)}


def adjust(rig, goal, setup=None):
    """Create Targets (the head's slot, if any, disabled); the right hand's target moved to ``goal(rig)`` (the
    other three where they stand); ``setup(rig, target)`` (obstacles); Adjust Pose. Returns (target, rotation
    changes, keyed bones)."""
    bpy.ops.fullbody_adjust.create_targets()
    for slot in rig.armature.fullbody_adjust.targets:  # the four hands and feet; no head target
        slot.enabled = slot.effector != "head"
    target = goal(rig)
    place_target(rig, "hand.R", target)
    if setup is not None:
        setup(rig, target)
    before_rot, before_keys = rm.local_rotations(rig.armature), rm.keys_snapshot(rig.armature)
    bpy.ops.fullbody_adjust.adjust_pose()
    return target, rm.rotation_changes(before_rot, rm.local_rotations(rig.armature)), \
        rm.keyed_bones(before_keys, rm.keys_snapshot(rig.armature))


def near_case(saved):
    rig = saved.open()
    target, changes, keyed = adjust(rig, near_target)
    arm = right_arm_bones(rig)
    outside = {b: d for b, d in changes.items() if b not in arm}
    worst = max(outside, key=outside.get)
    return {"keyed_bones": len(keyed), "keyed_outside_right_arm": sorted(set(keyed) - arm),
            "max_rotation_outside_right_arm_deg": outside[worst], "that_bone": worst,
            "residual_m": metres(rig, np.linalg.norm(wrist_of(rig) - target))}


def far_case(saved):
    rig = saved.open()
    knees = [rig.joints["knee.L"], rig.joints["knee.R"]]
    hips_line = joint(rig, "hip.L") - joint(rig, "hip.R")
    hips_line /= np.linalg.norm(hips_line)
    knees_before = rm.world_heads(rig.armature, knees)
    start = {}

    def far(r):
        start["arm"] = arm_of(r)
        shoulder, _, _, reach = start["arm"]
        return shoulder + 1.8 * reach * r.facing + 0.1 * reach * rm.UP

    target, _, _ = adjust(rig, far)
    shoulder, _, wrist, reach = start["arm"]
    knees_after = rm.world_heads(rig.armature, knees)
    sideways = (knees_after - knees_before) @ hips_line
    return {"residual_m": metres(rig, np.linalg.norm(wrist_of(rig) - target)),
            "beyond_arm_m": metres(rig, np.linalg.norm(target - shoulder) - reach),
            "wrist_gained_m": metres(rig, np.linalg.norm(target - wrist) - np.linalg.norm(wrist_of(rig) - target)),
            "knee_sideways_mm": {"L": metres(rig, sideways[0]) * 1e3, "R": metres(rig, sideways[1]) * 1e3}}


def obstacle_case(saved):
    """The near click once without an obstacle, to see where the forearm goes; then again from the saved file
    with a box (edge 0.3 forearm lengths) centred on that forearm's middle. Mesh vertices inside the box are
    counted in all, and those of the hand (weighted most to the mapped hand bone or a bone below it): the hand
    is placed by the target and keeps its world orientation (DESIGN §1), so what its mesh puts in the box at the
    target no pose of the arm takes out, and the unobstructed pose shows how much that is."""
    rig = saved.open()
    target, _, _ = adjust(rig, near_target)
    _, elbow, wrist, _ = arm_of(rig)
    centre, size = 0.5 * (elbow + wrist), 0.3 * float(np.linalg.norm(wrist - elbow))
    lo, hi = centre - 0.5 * size, centre + 0.5 * size
    hand = hand_owned(rig)
    in_the_way = rm.mesh_vertices(rig.meshes)
    rig = saved.open()
    before = {}

    def add_box(r, _target):
        bpy.ops.mesh.primitive_cube_add(size=size, location=tuple(centre))
        bpy.context.active_object.name = "Obstacle"
        bpy.context.view_layer.objects.active = r.armature
        before["inside"] = rm.vertices_inside(rm.mesh_vertices(r.meshes), lo, hi)

    target, _, _ = adjust(rig, near_target, add_box)
    after = rm.mesh_vertices(rig.meshes)
    depth = np.minimum(after - lo, hi - after).min(axis=1)  # > 0 inside the box
    return {"joints_inside": rm.vertices_inside(rm.world_heads(rig.armature), lo, hi),
            "deepest_arm_vertex_m": metres(rig, max(0.0, float(depth[~hand].max()))),
            "mesh_vertices_inside": rm.vertices_inside(after, lo, hi),
            "hand_vertices_inside": rm.vertices_inside(after[hand], lo, hi),
            "mesh_vertices_inside_before": before["inside"],
            "mesh_vertices_in_the_way": rm.vertices_inside(in_the_way, lo, hi),
            "hand_vertices_in_the_way": rm.vertices_inside(in_the_way[hand], lo, hi),
            "residual_m": metres(rig, np.linalg.norm(wrist_of(rig) - target))}


def hand_owned(rig, side="R"):
    """(n,) bool over rm.mesh_vertices(rig.meshes): the vertices whose largest weight is the mapped hand bone's
    or that of a bone below it (none on an arm mapped without a hand)."""
    names = [bone for bone in bone_map(rig.armature).get(f"hand.{side}", []) if bone]
    bones = rig.armature.data.bones
    hand = set(names) | {b.name for name in names for b in bones[name].children_recursive}
    out = []
    for mesh in rig.meshes:
        groups = [g.name for g in mesh.vertex_groups]
        out.extend(bool(v.groups) and groups[max(v.groups, key=lambda g: g.weight).group] in hand
                   for v in mesh.data.vertices)
    return np.array(out, dtype=bool)


def retarget_case(saved, folder, cli):
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
    said = io.StringIO()
    with contextlib.redirect_stderr(said):
        code = cli.main(argv)
    out = {"exit_code": code}
    lines = [line for line in said.getvalue().splitlines() if line.strip()]
    if code != 0 and lines:
        out["stderr_last_line"] = lines[-1][:400]
    if not path_out.exists():
        out["error"] = "no output written" + (f": {lines[-1][:400]}" if lines else "")
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
    soles_planted, soles_all, slide, soles, source_slide = [], [], [], {}, []
    for side in ("L", "R"):
        planted, which = rm.plants(source_track[f"ankle.{side}"], source_track.get(f"ball.{side}"), FPS, mpu)
        sole = rm.sole_heights(rig, side, verts)
        if sole is not None:
            soles_planted.append(sole[planted])
            soles_all.append(sole)
            soles[side] = sole
        slide.append(rm.slides(planted, which, {"ankle": track[f"ankle.{side}"], "ball": track.get(f"ball.{side}")})
                     * mpu)
        source_slide.append(rm.slides(planted, which, {"ankle": source_track[f"ankle.{side}"],
                                                       "ball": source_track.get(f"ball.{side}")}) * mpu)
    planted_soles = np.concatenate(soles_planted) if soles_planted else np.zeros(0)
    all_soles = np.concatenate(soles_all) if soles_all else np.zeros(0)
    slide = np.concatenate(slide)
    angles = rm.limb_direction_angles(track, source_track)
    source_facing = rm.body_frames(source_track["hip.L"], source_track["hip.R"])[:, 1].mean(axis=0)
    facing = rm.body_frames(track["hip.L"], track["hip.R"])[:, 1].mean(axis=0)
    heading = rm.heading_error(track["hips"], facing, source_track["hips"], source_facing)
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
        "source_slide_p95_mm": float(np.percentile(np.concatenate(source_slide), 95)) * mm if slide.size else None,
        "limb_direction_median_deg": float(np.median(angles)) if angles.size else None,
        "heading_error_deg": heading,
        "pop_frames": len(rm.pop_frames(rots)), "source_pop_frames": len(rm.pop_frames(source_rots)),
        "largest_step_deg": rm.largest_step(rots), "source_largest_step_deg": rm.largest_step(source_rots),
        "report_vs_measured": report_agreement(rig, contacts, frames, soles),
    }


def retarget_clip_file(saved, folder, cli, clip, tag, take=None):
    """The open scene saved as ``tag``.blend in ``folder``, the clip file ``clip`` retargeted onto the saved rig with
    `retarget FILE --target RIG --source-file CLIP [--take TAKE] --jobs 1` (cli.main), the result reopened and the
    clip imported again with Blender's importer (defaults), given the take the batch carried (``take``, else the
    longest action the import made) with its first key moved onto the result's first frame, as the batch does.
    Returns (out, target, source, frames): out {"exit_code"} (with "error", and None for the rest, when the clip's
    row is not done), the two armatures and the result's frames."""
    path_in, path_out, report_path = (folder / f"{tag}{ext}" for ext in (".blend", "_out.blend", ".json"))
    bpy.ops.wm.save_as_mainfile(filepath=str(path_in))
    said = io.StringIO()
    with contextlib.redirect_stderr(said):
        code = cli.main(["retarget", str(path_in), "--target", saved.armature_name, "--source-file", str(clip),
                         *(("--take", take) if take else ()), "--jobs", "1", "--output", str(path_out),
                         "--report", str(report_path), "--quiet"])
    out = {"exit_code": code}
    row = json.loads(report_path.read_text())["rows"][0] if report_path.exists() else {}
    if row.get("status") != "done":
        out["error"] = f"exit {code}: {row.get('reason') or said.getvalue().strip()[-300:]}"
        return out, None, None, None
    reopen(path_out)
    target = bpy.data.objects[saved.armature_name]
    rm.assign_action(target, bpy.data.actions[row["action"]])
    before = set(bpy.data.actions)
    source = next(ob for ob in real_rigs.import_file(clip) if ob.type == 'ARMATURE')
    takes = [a for a in bpy.data.actions if a not in before]
    rm.assign_action(source, next(a for a in takes if a.name.rsplit("|", 1)[-1].startswith(take)) if take else
                     max(takes, key=lambda a: a.frame_range[1] - a.frame_range[0]))
    rm.shift_keys(source, row["frame_start"] - source.animation_data.action.frame_range[0])
    return out, target, source, np.arange(int(row["frame_start"]), int(row["frame_end"]) + 1)


def clip_case(saved, folder, cli, clip_name="kenney_run", take=None):
    """A clip file of the corpus (its own character's skeleton) retargeted onto the saved rig with
    `retarget FILE --target RIG --source-file CLIP [--take TAKE] --jobs 1` (cli.main); the written action and the
    clip imported again with Blender's importer (defaults; the clip is given the take the batch carries: ``take``,
    else the longest action the import made (Kenney's run, not the 1-frame 'Targeting Pose' the importer makes
    active); its first key moved onto the result's first frame, as the batch does with a glTF take; source_action
    and frames say which) are measured on the same frames: pop frames of each, and the limb directions against
    each other."""
    saved.open()
    clip = real_rigs.RIGS_DIR / real_rigs.CLIP_FILES[clip_name]
    source_joints = real_rigs.CORPUS[real_rigs.CLIP_CHARACTER[clip_name]]["joints"]
    out, target, source, frames = retarget_clip_file(saved, folder, cli, clip, f"{saved.name}_{clip_name}_{take}",
                                                     take)
    if target is None:
        return out
    roles = [r for r, b in saved.rig.joints.items() if b and source_joints.get(r)]
    (heads, source_heads), (rots, source_rots), _ = rm.sample(
        frames, [(target, [saved.rig.joints[r] for r in roles]), (source, [source_joints[r] for r in roles])])
    limbs = [i for i, r in enumerate(roles) if r.split(".")[0] in rm.POP_ROLES]
    angles = rm.limb_direction_angles({r: heads[:, i] for i, r in enumerate(roles)},
                                      {r: source_heads[:, i] for i, r in enumerate(roles)})
    out.update({"clip": clip.name, "source_action": source.animation_data.action.name, "frames": len(frames),
                "pop_frames": len(rm.pop_frames(rots[:, limbs])),
                "source_pop_frames": len(rm.pop_frames(source_rots[:, limbs])),
                "largest_step_deg": rm.largest_step(rots[:, limbs]),
                "source_largest_step_deg": rm.largest_step(source_rots[:, limbs]),
                "limb_direction_median_deg": float(np.median(angles)) if angles.size else None})
    return out
