"""Clips the retargeting was not tuned on ("clips from the wild", issue 27 item 6), retargeted onto a saved rig
through the command-line function and measured from Blender's evaluation of the written file, against the clip
itself on the same frames (tests/helpers/rig_measures.py holds the definitions):

  pops            pop frames of the result's and of the clip's hips, upper arms, forearms, thighs and shins;
  slide           p95 over the clip's plants (ankle or ball < 0.2 m/s within 6 cm of the clip's floor, its lowest
                  ankle or ball of both feet, for >= 0.1 s) of the result's planted joint's horizontal slide, and
                  of the clip's own (mm); and the result's divided by the legs' ratio (result / clip, hip to knee
                  to ankle on the first frame), to compare with the clip's at its size;
  soles           the result's mesh soles (its skinned foot vertices' lowest point) on the planted frames: p95 of
                  |height| and the lowest (mm, the floor at 0);
  limbs           median angle of the limb segments against the clip's, each in its body's frame (degrees);
  exit_code       of `retarget`.

Clips (CLIPS): the CMU BVH clips of tests/data/mocap other than the walk (imported with Blender's BVH importer
into the rig's file, 24 fps, keys scaled, `--source Source --floor 0`, from frame 2: frame 1 is the conversion's
T-pose), and the corpus's animation files kenney_jump.fbx, kenney_idle.fbx and every take of
kaykit_Med_MovementAdvanced.glb (`--source-file CLIP [--take TAKE]`; the clip imported again with Blender's
importer, its take's first key moved onto the result's first frame).

  wild_case(saved, folder, cli, clip, take=None) -> dict of figures
"""

import contextlib
import io

import bpy
import numpy as np

from tests.helpers import real_rigs, rig_measures as rm
from tests.helpers.bvh import CMU_SCALE, MOCAP_DIR
from tests.helpers.rig_scenarios import CMU_JOINTS, FIRST_FRAME, FPS, reopen, retarget_clip_file

CLIPS = {
    "cmu_jump": dict(bvh="cmu_02_04_jump.bvh"),
    "cmu_dance": dict(bvh="cmu_05_02_dance.bvh"),
    "cmu_pickup": dict(bvh="cmu_02_06_pickup_f0-1349.bvh"),
    "cmu_climb_sit": dict(bvh="cmu_01_06_climb_sit_f360-1559.bvh"),
    "kenney_jump": dict(file="kenney_jump.fbx", character="kenney"),
    "kenney_idle": dict(file="kenney_idle.fbx", character="kenney"),
    "kaykit_advanced": dict(file="kaykit_Med_MovementAdvanced.glb", character="kaykit_manny"),
}
KAYKIT_ADVANCED_TAKES = ("Crawling", "Crouching", "Dodge_Backward", "Dodge_Forward", "Dodge_Left", "Dodge_Right",
                         "Running_HoldingBow", "Running_HoldingRifle", "Running_Strafe_Left",
                         "Running_Strafe_Right", "Sneaking", "Walking_Backwards")  # and a 1-frame T-Pose


def _run(cli, argv):
    said = io.StringIO()
    with contextlib.redirect_stderr(said):
        code = cli.main(argv)
    return code, said.getvalue()


def wild_case(saved, folder, cli, clip, take=None):
    spec = CLIPS[clip]
    rig = saved.open()
    bpy.context.scene.render.fps = FPS
    tag = f"{saved.name}_{clip}_{take}"
    path_in, path_out, report_path = (folder / f"{tag}{ext}" for ext in (".blend", "_out.blend", ".json"))
    if "bvh" in spec:
        if "io_anim_bvh" not in bpy.context.preferences.addons:
            bpy.ops.preferences.addon_enable(module="io_anim_bvh")
        bpy.ops.import_anim.bvh(filepath=str(MOCAP_DIR / spec["bvh"]), global_scale=CMU_SCALE / rig.metres_per_unit,
                                update_scene_fps=False, update_scene_duration=True, use_fps_scale=True)
        source = bpy.context.active_object
        source.name = "Source"
        last = int(np.floor(source.animation_data.action.frame_range[1]))
        bpy.ops.wm.save_as_mainfile(filepath=str(path_in))
        code, said = _run(cli, ["retarget", str(path_in), "--source", "Source", "--target", saved.armature_name,
                                "--frame-start", str(FIRST_FRAME), "--frame-end", str(last), "--floor", "0",
                                "--output", str(path_out), "--report", str(report_path), "--quiet"])
        out = {"exit_code": code}
        if not path_out.exists():
            out["error"] = f"exit {code}: {said.strip()[-300:]}"
            return out
        reopen(path_out)
        target, source = bpy.data.objects[saved.armature_name], bpy.data.objects["Source"]
        frames = np.arange(FIRST_FRAME, last + 1)
        source_joints, source_mpu = CMU_JOINTS, rig.metres_per_unit
    else:
        out, target, source, frames = retarget_clip_file(saved, folder, cli, real_rigs.RIGS_DIR / spec["file"], tag,
                                                         take)
        if target is None:
            return out
        source_joints, source_mpu = real_rigs.CORPUS[spec["character"]]["joints"], 1.0
    rig.armature = target
    rig.meshes = [bpy.data.objects[n] for n in saved.mesh_names]
    out.update(measure(rig, target, source, source_joints, frames, source_mpu))
    out["source_action"] = source.animation_data.action.name
    return out


def leg(track):
    """Hip joint to knee to ankle on the first frame, the mean of both legs (world units)."""
    return float(np.mean([np.linalg.norm(track[f"knee.{s}"][0] - track[f"hip.{s}"][0])
                          + np.linalg.norm(track[f"ankle.{s}"][0] - track[f"knee.{s}"][0]) for s in "LR"]))


def measure(rig, target, source, source_joints, frames, source_mpu):
    """The figures of the module's docstring, sampling both armatures (and the rig's meshes) over ``frames``."""
    roles = [r for r, b in rig.joints.items() if b]
    source_roles = [r for r in rig.joints if source_joints.get(r)]
    (heads, source_heads), (rots, source_rots), verts = rm.sample(
        frames, [(target, [rig.joints[r] for r in roles]), (source, [source_joints[r] for r in source_roles])],
        rig.meshes)
    track = {r: heads[:, i] for i, r in enumerate(roles)}
    source_track = {r: source_heads[:, i] for i, r in enumerate(source_roles)}
    mpu = rig.metres_per_unit
    planted_soles, slide, source_slide, planted_frames = [], [], [], 0
    floor = min(float(source_track[r][:, 2].min()) for r in source_track if r.split(".")[0] in ("ankle", "ball"))
    for side in ("L", "R"):  # the clip's floor: the lowest ankle or ball of both feet (one may never come down)
        planted, which = rm.plants(source_track[f"ankle.{side}"], source_track.get(f"ball.{side}"), FPS, source_mpu,
                                   floor)
        planted_frames += int(planted.sum())
        sole = rm.sole_heights(rig, side, verts)
        if sole is not None:
            planted_soles.append(sole[planted])
        slide.append(rm.slides(planted, which, {"ankle": track[f"ankle.{side}"], "ball": track.get(f"ball.{side}")})
                     * mpu)
        source_slide.append(rm.slides(planted, which, {"ankle": source_track[f"ankle.{side}"],
                                                       "ball": source_track.get(f"ball.{side}")}) * source_mpu)
    soles = np.concatenate(planted_soles) if planted_soles else np.zeros(0)
    slide, source_slide = np.concatenate(slide), np.concatenate(source_slide)
    angles = rm.limb_direction_angles(track, source_track)
    limbs = [i for i, r in enumerate(roles) if r.split(".")[0] in rm.POP_ROLES and r in source_roles]
    source_limbs = [source_roles.index(roles[i]) for i in limbs]
    rots, source_rots = rots[:, limbs], source_rots[:, source_limbs]
    ratio = leg(track) * mpu / (leg(source_track) * source_mpu)
    mm = 1e3

    def p95(values):
        return float(np.percentile(values, 95)) * mm if values.size else None

    return {
        "frames": len(frames), "planted_frames": planted_frames,
        "pop_frames": len(rm.pop_frames(rots)), "source_pop_frames": len(rm.pop_frames(source_rots)),
        "largest_step_deg": rm.largest_step(rots), "source_largest_step_deg": rm.largest_step(source_rots),
        "slide_p95_mm": p95(slide), "source_slide_p95_mm": p95(source_slide), "leg_ratio": ratio,
        "slide_p95_at_source_size_mm": p95(slide / ratio),
        "sole_planted_p95_mm": p95(np.abs(soles)),
        "sole_planted_min_mm": float(soles.min()) * mm if soles.size else None,
        "limb_direction_median_deg": float(np.median(angles)) if angles.size else None,
    }
