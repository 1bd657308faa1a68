"""`retarget --source-file`: clip files (short cuts of the repository's CMU clips, and broken ones) retargeted
onto a character in 2 worker processes, through cli.main as `blender -c` would call it; the outputs reopened.
Also the frame-range refusal of `adjust` before any work."""

import csv
import importlib
import json
import os
from pathlib import Path
import sys

import bpy
import numpy as np
import pytest

from tests.helpers.bvh import MOCAP_DIR, cut_bvh
from tests.helpers.rig_measures import assign_action

from .test_cli import Untouched, keyed_values, reopen, run

CUTS = {"walk_a": ("cmu_07_01_walk.bvh", 1, 100), "walk_b": ("cmu_07_01_walk.bvh", 150, 260),
        "jump": ("cmu_02_04_jump.bvh", 1, 90)}  # name: (clip, first, last frame line, 0-based, end excluded)


def good_clips(tmp_path):
    """A folder of the three good clip cuts (CUTS)."""
    folder = tmp_path / "clips"
    folder.mkdir()
    for name, (clip, first, last) in CUTS.items():
        cut_bvh(MOCAP_DIR / clip, folder / f"{name}.bvh", first, last)
    return folder


@pytest.fixture
def clips(tmp_path):
    """A folder of three good clip cuts and a corrupt one (its header cut off mid-hierarchy)."""
    folder = good_clips(tmp_path)
    (folder / "broken.bvh").write_text((MOCAP_DIR / "cmu_07_01_walk.bvh").read_text()[:400])
    return folder


@pytest.fixture
def character(tmp_path, rig):
    return save_character(tmp_path, rig)


def save_character(tmp_path, rig):
    """A .blend with the Rigify basic metarig named 'Hero' and nothing else."""
    rig.name = "Hero"
    path = tmp_path / "hero.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(path))
    bpy.ops.wm.read_homefile(use_empty=True)
    return path


def scene_frames(path):
    """The whole scene frames a clip cut covers at the scene's 24 fps, imported as the batch does (its keys 1/5
    of a frame apart at 120 fps, from frame 1)."""
    count = int(Path(path).read_text().split("Frames:", 1)[1].split()[0])
    return 1, 1 + (count - 1) * 24 // 120


def test_clips_become_actions_of_the_target_and_a_broken_clip_is_reported(cli, capsys, tmp_path, clips, character):
    before = Untouched(character)
    out, report_path = tmp_path / "out.blend", tmp_path / "batch.json"
    code, stdout, err = run(cli, capsys, "retarget", character, "--target", "Hero", "--source-file", clips,
                            "--jobs", 2, "--output", out, "--report", report_path)
    before.check()
    assert code == 1, err  # the broken clip fails the batch, at the end
    report = json.loads(report_path.read_text())
    rows = {row["name"]: row for row in report["rows"]}
    assert sorted(rows) == sorted([*CUTS, "broken"])
    assert rows["broken"]["status"] == "failed" and "Cannot import broken.bvh" in rows["broken"]["reason"]
    assert f"broken.bvh failed: {rows['broken']['reason']}" in err
    assert "clips/min" in err  # the batch's progress line
    assert report["clips"] == {"total": 4, "done": 3, "failed": 1, "skipped": 0} and report["jobs"] == 2
    assert "3 of 4 clips retargeted" in stdout

    reopen(out)
    assert [ob.name for ob in bpy.data.objects if ob.type == 'ARMATURE'] == ["Hero"]  # no imported source left
    for name in CUTS:
        row = rows[name]
        assert row["status"] == "done" and row["reason"] is None and row["action"] == name
        action = bpy.data.actions[name]
        assert action.use_fake_user
        keyed = {float(f) for frames, _ in keyed_values(action).values() for f in frames}
        first, last = scene_frames(clips / f"{name}.bvh")
        assert (row["frame_start"], row["frame_end"], row["frames"]) == (first, last, last - first + 1)
        assert keyed == set(map(float, range(first, last + 1)))
        assert row["contact_frames"] > 0 and row["solve_seconds"] <= row["seconds"]  # the feet plant
        assert row["contacts_not_held"] == 0 and row["contact_error_max"] < 1e-4
    assert bpy.data.objects["Hero"].animation_data is None  # the target's own motion is as it was (none)

    # Resumed on its own output: the clips it holds are left out, the broken one is tried (and fails) again.
    code, stdout, _ = run(cli, capsys, "retarget", out, "--target", "Hero", "--source-file", clips, "--jobs", 2,
                          "--overwrite", "--skip-existing", "--quiet", "--report", tmp_path / "again.json")
    again = {row["name"]: row["status"] for row in json.loads((tmp_path / "again.json").read_text())["rows"]}
    assert code == 1 and again == {**{name: "skipped" for name in CUTS}, "broken": "failed"}
    reopen(out)
    assert sorted(a.name for a in bpy.data.actions) == sorted(CUTS)  # nothing added twice

    # The CSV beside the JSON holds the same rows.
    with open(report_path.with_suffix(".csv"), newline="") as table:
        listed = list(csv.DictReader(table))
    assert [r["name"] for r in listed] == [r["name"] for r in report["rows"]]
    for text_row, row in zip(listed, report["rows"]):
        for column, value in row.items():
            if value is None:
                assert text_row[column] == "", column
            elif isinstance(value, (int, float)):
                assert float(text_row[column]) == pytest.approx(value, rel=1e-12), column
            else:
                assert text_row[column] == str(value), column


def test_output_dir_writes_one_blend_per_clip_and_skip_existing_resumes(cli, capsys, tmp_path, clips, character):
    os.remove(clips / "broken.bvh")
    os.remove(clips / "jump.bvh")
    folder = tmp_path / "out"
    code, _, err = run(cli, capsys, "retarget", character, "--target", "Hero", "--source-file", clips / "walk_*.bvh",
                       "--jobs", 2, "--output-dir", folder, "--quiet")
    report_code = code
    assert sorted(p.name for p in folder.iterdir()) == ["walk_a.blend", "walk_b.blend"]
    for name in ("walk_a", "walk_b"):
        reopen(folder / f"{name}.blend")
        assert [ob.name for ob in bpy.data.objects if ob.type == 'ARMATURE'] == ["Hero"]
        assert bpy.data.objects["Hero"].animation_data.action.name == name
        assert [a.name for a in bpy.data.actions] == [name]
    assert report_code in (0, 1) and "failed" not in err

    # Resume with one clip more: the two done are left alone, only the new one runs.
    cut_bvh(MOCAP_DIR / "cmu_02_04_jump.bvh", clips / "walk_c.bvh", 1, 60)
    done_before = {p.name: p.stat().st_mtime_ns for p in folder.iterdir()}
    code, stdout, _ = run(cli, capsys, "retarget", character, "--target", "Hero", "--source-file", clips,
                          "--jobs", 2, "--output-dir", folder, "--skip-existing", "--quiet", "--report",
                          tmp_path / "again.json")
    rows = {row["name"]: row["status"] for row in json.loads((tmp_path / "again.json").read_text())["rows"]}
    assert rows == {"walk_a": "skipped", "walk_b": "skipped", "walk_c": "done"}
    assert {p.name: p.stat().st_mtime_ns for p in folder.iterdir() if p.name in done_before} == done_before
    assert (folder / "walk_c.blend").exists() and "2 skipped" in stdout


def test_the_batch_report_states_the_options_that_shaped_the_clips(cli, capsys, tmp_path, clips, character):
    """One clip in place and mirrored, with the default root smoothing and with 0.5 s: the report's options say so
    (the default smoothing the solver's own), and the hips run's none."""
    from fullbody_adjust.solver.retarget.root_motion import DEFAULT_SMOOTHING

    found = {}
    for label, extra in (("default", ["--root-motion", "in-place", "--mirror"]),
                         ("half", ["--root-motion", "in-place", "--root-smoothing", 0.5]), ("hips", [])):
        report = tmp_path / f"{label}.json"
        code, _, _ = run(cli, capsys, "retarget", character, "--target", "Hero", "--source-file", clips / "walk_a.bvh",
                         "--jobs", 1, "--output-dir", tmp_path / label, "--quiet", "--report", report, *extra)
        assert code in (0, 1)
        found[label] = json.loads(report.read_text())["options"]
    assert found["default"]["root_motion"] == "in-place" and found["default"]["mirror"] is True
    assert found["default"]["root_smoothing"] == DEFAULT_SMOOTHING
    assert found["half"]["root_smoothing"] == 0.5 and found["half"]["mirror"] is False
    assert found["hips"]["root_motion"] in (None, "hips") and found["hips"]["root_smoothing"] is None
    assert found["hips"]["contacts"] == [["ground", None]] and found["hips"]["format"] == "blend"


def test_an_fbx_clip_through_blenders_fbx_importer_and_kept_sources(cli, capsys, tmp_path, clips, character,
                                                                     extension_module_name):
    # An FBX of a clip, written by Blender's FBX exporter from the imported BVH.
    import addon_utils

    clip_import = importlib.import_module(f"{extension_module_name}.bridge.retarget.clip_import")
    source, _ = clip_import.import_clip(bpy.context, str(clips / "jump.bvh"))
    addon_utils.enable("io_scene_fbx", default_set=False)
    bpy.ops.object.select_all(action='DESELECT')
    source.select_set(True)
    bpy.context.scene.frame_end = 20
    fbx = tmp_path / "jump_fbx.fbx"
    bpy.ops.export_scene.fbx(filepath=str(fbx), use_selection=True, object_types={'ARMATURE'}, add_leaf_bones=False,
                             bake_anim=True, bake_anim_use_nla_strips=False, bake_anim_use_all_actions=False)
    out = tmp_path / "out.blend"
    code, _, err = run(cli, capsys, "retarget", character, "--target", "Hero", "--source-file", fbx, "--jobs", 1,
                       "--keep-sources", "--output", out, "--report", tmp_path / "r.json", "--quiet")
    row = json.loads((tmp_path / "r.json").read_text())["rows"][0]
    assert row["status"] == "done", row["reason"]
    assert code == (1 if row["missed_within_reach"] else 0)
    reopen(out)
    kept = sorted(ob.name for ob in bpy.data.objects if ob.type == 'ARMATURE')
    assert kept == ["Hero", "jump"]  # the source, named as the exported object
    action = bpy.data.actions["jump_fbx"]
    keyed = {float(f) for frames, _ in keyed_values(action).values() for f in frames}
    assert len(keyed) == row["frames"] == 20 and min(keyed) == row["frame_start"]


def test_an_fbx_with_several_takes_carries_the_motion_not_the_pose(cli, capsys, tmp_path, character):
    """Kenney's run (tests/data/rigs, CC0) holds a one-frame 'Targeting Pose' beside the run, and Blender's FBX
    importer makes the pose the armature's action: the batch carries the run's frames."""
    clip = Path(__file__).resolve().parents[1] / "data" / "rigs" / "kenney_run.fbx"
    code, _, err = run(cli, capsys, "retarget", character, "--target", "Hero", "--source-file", clip, "--jobs", 1,
                       "--output", tmp_path / "out.blend", "--report", tmp_path / "r.json", "--quiet")
    row = json.loads((tmp_path / "r.json").read_text())["rows"][0]
    assert row["status"] == "done", row["reason"]
    import addon_utils
    bpy.ops.wm.read_homefile(use_empty=True)
    addon_utils.enable("io_scene_fbx", default_set=False)
    bpy.ops.import_scene.fbx(filepath=str(clip))
    takes = {a.name: a.frame_range[1] - a.frame_range[0] + 1 for a in bpy.data.actions}
    assert sorted(takes.values()) == [2, 17]  # the pose and the run, as the importer reads them
    assert row["frames"] == max(takes.values()) > 2


def test_the_blender_worker_command_runs_the_worker_loop(tmp_path, clips, character, extension_module_name):
    # Under Blender a worker is `blender -b --factory-startup --python-expr CODE`; no Blender binary here, so CODE
    # runs in this Python (with the bpy module) and serves one clip through the pool.
    cli_clips = importlib.import_module(f"{extension_module_name}.cli.clips")
    pool_module = importlib.import_module(f"{extension_module_name}.cli.pool")
    command = cli_clips.worker_command("/opt/blender/blender")
    assert command[:4] == ["/opt/blender/blender", "-b", "--factory-startup", "--python-expr"]
    job = {"file": str(character), "target": "Hero", "import": {}, "floor": 0.0}
    task = {"clip": str(clips / "jump.bvh"), "name": "jump", "out": str(tmp_path / "jump.blend")}
    [row] = pool_module.WorkerPool([sys.executable, "-c", command[4]], job, 1, env=cli_clips.worker_env()).run([task])
    assert row["status"] == "done", row.get("reason")
    reopen(tmp_path / "jump.blend")
    assert bpy.data.objects["Hero"].animation_data.action.name == "jump"


def test_workers_run_openblas_on_one_thread_unless_the_user_chose(monkeypatch, extension_module_name):
    cli_clips = importlib.import_module(f"{extension_module_name}.cli.clips")
    monkeypatch.delenv("OPENBLAS_NUM_THREADS", raising=False)
    assert cli_clips.worker_env()["OPENBLAS_NUM_THREADS"] == "1"
    monkeypatch.setenv("OPENBLAS_NUM_THREADS", "3")
    assert cli_clips.worker_env()["OPENBLAS_NUM_THREADS"] == "3"


def test_an_interrupted_batch_keeps_the_clips_done_and_resumes(cli, capsys, tmp_path, clips, character,
                                                               monkeypatch, extension_module_name):
    os.remove(clips / "broken.bvh")
    batch = importlib.import_module(f"{extension_module_name}.bridge.files")
    append = batch.append_datablocks

    def append_then_interrupt(context, path):  # Ctrl+C right after the first clip joined the file
        appended = append(context, path)
        monkeypatch.setattr(batch, "append_datablocks", append)
        raise KeyboardInterrupt

    monkeypatch.setattr(batch, "append_datablocks", append_then_interrupt)
    out, report_path = tmp_path / "out.blend", tmp_path / "r.json"
    code, _, err = run(cli, capsys, "retarget", character, "--target", "Hero", "--source-file", clips, "--jobs", 1,
                       "--output", out, "--report", report_path, "--quiet")
    rows = json.loads(report_path.read_text())["rows"]
    assert code == 1 and "interrupted" in err and "--skip-existing" in err
    first = max(rows, key=lambda row: os.path.getsize(row["clip"]))["name"]  # the largest clip starts first
    assert [row["name"] for row in rows] == ["jump", "walk_a", "walk_b"]  # rows in name order
    assert [row["status"] for row in rows] == ["done" if row["name"] == first else "failed" for row in rows]
    assert [row["reason"] for row in rows if row["name"] != first] == ["interrupted before it ended"] * 2
    reopen(out)
    assert sorted(a.name for a in bpy.data.actions) == [first]

    code, _, _ = run(cli, capsys, "retarget", out, "--target", "Hero", "--source-file", clips, "--jobs", 2,
                     "--overwrite", "--skip-existing", "--report", report_path, "--quiet")
    rows = json.loads(report_path.read_text())["rows"]
    assert [row["status"] for row in rows] == ["skipped" if row["name"] == first else "done" for row in rows]
    reopen(out)
    assert sorted(a.name for a in bpy.data.actions) == ["jump", "walk_a", "walk_b"]


@pytest.mark.parametrize("extra, words", [
    (["--source-file", "{tmp}/none.bvh"], "no such file"),
    (["--source-file", "{clips}/walk_a.bvh", "--source", "Hero"], "not allowed with argument"),
    (["--source-file", "{clips}", "--new-action", "One"], "--new-action names one action"),
    (["--source-file", "{clips}", "--target", "Nobody", "--output-dir", "{tmp}/d"], "no object named 'Nobody'"),
    (["--source-file", "{clips}", "--output-dir", "{tmp}/no/d"], "does not exist"),
    (["--source-file", "{clips}", "--output-dir", "{tmp}/d", "--output", "{tmp}/o.blend"], "--output-dir"),
])
def test_bad_batch_input_exits_2_before_any_work(cli, capsys, tmp_path, clips, character, extra, words):
    before = Untouched(character)
    argv = [a.format(tmp=tmp_path, clips=clips) for a in extra]
    if "--target" not in argv:
        argv += ["--target", "Hero"]
    code, _, err = run(cli, capsys, "retarget", character, *argv, "--quiet")
    assert code == 2 and len(err.strip().splitlines()) == 1 and words in err, err
    before.check()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["clips", "hero.blend"]


def test_a_frame_range_far_beyond_the_animation_is_refused_in_one_line(cli, capsys, tmp_path, character):
    before = Untouched(character)
    out = tmp_path / "out.blend"
    code, _, err = run(cli, capsys, "adjust", character, "--armature", "Hero", "--frame-start", 1, "--frame-end",
                       1_000_000, "--output", out, "--report", tmp_path / "r.json")
    assert code == 2 and len(err.strip().splitlines()) == 1, err
    assert "far beyond the animation" in err and "frames 1..250" in err
    assert "reading" not in err  # refused before the reading started
    before.check()
    assert not out.exists() and not (tmp_path / "r.json").exists()


def test_a_frame_range_too_large_for_memory_is_refused_in_one_line(cli, capsys, tmp_path, character, monkeypatch,
                                                                   extension_module_name):
    batch = importlib.import_module(f"{extension_module_name}.bridge.files")
    bones = 29  # the basic metarig
    need = 10 * bones * batch.BYTES_PER_BONE_FRAME  # frames 1..10
    monkeypatch.setattr(batch, "available_memory", lambda: 2 * need - 1)
    code, _, err = run(cli, capsys, "adjust", character, "--armature", "Hero", "--frame-start", 1, "--frame-end", 10,
                       "--quiet")
    assert code == 2 and len(err.strip().splitlines()) == 1 and "would need about" in err, err
    monkeypatch.setattr(batch, "available_memory", lambda: 2 * need)  # exactly half: allowed
    code, _, err = run(cli, capsys, "adjust", character, "--armature", "Hero", "--frame-start", 1, "--frame-end", 10,
                       "--quiet")
    assert "would need" not in err


def test_retarget_frames_default_to_the_source_action_within_the_scene_range(cli, capsys, tmp_path):
    samples = Path(__file__).resolve().parents[2] / "sample_scenes"
    reopen(samples / "retarget_cmu.blend")
    action = bpy.data.objects["Source"].animation_data.action
    first, last = (int(round(f)) for f in action.frame_range)
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = first + 4, first + 9  # shorter than the action, inside it
    path = tmp_path / "short.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(path))
    run(cli, capsys, "retarget", path, "--source", "Source", "--target", "Small", "--quiet", "--report",
        tmp_path / "r.json")
    assert json.loads((tmp_path / "r.json").read_text())["frames"] == {"start": first + 4, "end": first + 9,
                                                                      "count": 6}


def test_floor_puts_the_ground_contacts_at_its_height(tmp_path, clips, character, extension_module_name):
    clip_import = importlib.import_module(f"{extension_module_name}.bridge.retarget.clip_import")
    retarget = importlib.import_module(f"{extension_module_name}.bridge.retarget.run")
    reopen(character)
    source, _ = clip_import.import_clip(bpy.context, str(clips / "walk_a.bvh"))
    hero = bpy.data.objects["Hero"]
    own = retarget.prepare(bpy.context, source, hero).plan
    raised = retarget.prepare(bpy.context, source, hero, floor=own.ground + 0.25).plan
    assert raised.ground == pytest.approx(own.ground + 0.25, abs=1e-9)
    assert own.contacts.any() and np.array_equal(raised.contacts, own.contacts)
    shift = raised.world_targets - own.world_targets  # the whole motion, contacts and all, 0.25 higher
    assert np.allclose(shift[..., :2], 0.0, atol=1e-9) and np.allclose(shift[..., 2], 0.25, atol=1e-9)


@pytest.mark.parametrize("scene_fps, step", [(120, 1.0), (24, 0.2)])
def test_a_clip_lands_on_the_scenes_frames(clips, extension_module_name, scene_fps, step):
    # CMU's frame time '.0083333' is 120.0005 fps: at 120 fps the keys sit exactly on the frames (not drifting off
    # them); at 24 fps they are resampled, 1/5 frame apart.
    clip_import = importlib.import_module(f"{extension_module_name}.bridge.retarget.clip_import")
    assert clip_import.bvh_frame_rate(clips / "walk_a.bvh") == pytest.approx(1 / 0.0083333)
    bpy.context.scene.render.fps = scene_fps
    source, _ = clip_import.import_clip(bpy.context, str(clips / "walk_a.bvh"))
    [times] = {tuple(frames) for frames, _ in keyed_values(source.animation_data.action).values()}
    expected = 1.0 + step * np.arange(99)
    assert np.allclose(times, expected, atol=1e-3 if step != 1.0 else 0.0)


def test_floor_with_a_source_in_the_file_raises_the_retargeted_motion(cli, capsys, tmp_path, extension_module_name):
    retarget = importlib.import_module(f"{extension_module_name}.bridge.retarget.run")
    samples = Path(__file__).resolve().parents[2] / "sample_scenes"
    reopen(samples / "retarget_cmu.blend")
    ground = retarget.prepare(bpy.context, bpy.data.objects["Source"], bpy.data.objects["Small"], 20, 22).plan.ground
    hips = {}
    for floor in (None, ground + 0.3):
        out = tmp_path / f"floor{floor}.blend"
        argv = ["retarget", samples / "retarget_cmu.blend", "--source", "Source", "--target", "Small", "--frame-start",
                20, "--frame-end", 22, "--output", out, "--quiet"] + (["--floor", floor] if floor is not None else [])
        code, _, err = run(cli, capsys, *argv)
        assert code in (0, 1), err
        reopen(out)
        bpy.context.scene.frame_set(21)
        small = bpy.data.objects["Small"]
        hips[floor] = np.array(small.matrix_world @ small.pose.bones["LeftUpLeg"].head)
    low, high = hips.values()
    assert high - low == pytest.approx([0.0, 0.0, 0.3], abs=1e-4)


def test_clips_over_the_time_limit_are_reported_failed(cli, capsys, tmp_path, clips, character):
    """--clip-timeout shorter than any clip's work: every clip's worker is stopped, each clip is reported failed
    with the limit as its reason, the batch exits 1 and writes nothing into the input file."""
    before = Untouched(character)
    report_path = tmp_path / "timed.json"
    code, _stdout, err = run(cli, capsys, "retarget", character, "--target", "Hero", "--source-file", clips,
                             "--jobs", 2, "--clip-timeout", 0.01, "--output", tmp_path / "timed.blend",
                             "--report", report_path)
    before.check()
    assert code == 1, err
    rows = json.loads(report_path.read_text())["rows"]
    assert len(rows) == len(CUTS) + 1
    assert all(row["status"] == "failed" and row["reason"] == "stopped after 0.01 s (the clip time limit)"
               for row in rows), rows


def test_a_target_with_a_negative_scale_is_refused_before_any_clip(cli, capsys, tmp_path, clips, rig):
    """As the single retarget does: one line, exit 2, no worker started for any clip."""
    rig.name = "Hero"
    rig.scale = (-1.0, 1.0, 1.0)
    path = tmp_path / "mirrored.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(path))
    bpy.ops.wm.read_homefile(use_empty=True)
    code, _, err = run(cli, capsys, "retarget", path, "--target", "Hero", "--source-file", clips,
                       "--output-dir", tmp_path / "out", "--quiet")
    assert code == 2 and len(err.strip().splitlines()) == 1 and "negative or zero scale" in err, err
    assert not (tmp_path / "out").exists()


KAYKIT_CLIPS = Path(__file__).resolve().parents[1] / "data" / "rigs" / "kaykit_Med_MovementBasic.glb"


def _leg_directions(obj, names, frames):
    """(F,2,3) world unit directions hip -> knee and knee -> ankle (bone heads ``names``) at float ``frames``."""
    scene = bpy.context.scene
    out = []
    for frame in frames:
        scene.frame_set(int(np.floor(frame)), subframe=float(frame - np.floor(frame)))
        heads = [np.array(obj.matrix_world @ obj.pose.bones[n].head) for n in names]
        segments = np.diff(heads, axis=0)
        out.append(segments / np.linalg.norm(segments, axis=1, keepdims=True))
    return np.array(out)


def test_a_gltf_clip_carries_the_take_asked_for_or_its_longest(cli, capsys, tmp_path, character):
    """KayKit's glTF move library (tests/data/rigs, CC0): 11 takes in one .glb, which Blender's glTF importer reads
    as one action each. `--take Running_A` carries the run, from the scene's frame 1, its legs as the clip moves
    them; without --take the longest take is carried; a take the file does not hold fails its row in one line
    naming the file's takes."""
    import addon_utils

    addon_utils.enable("io_scene_gltf2", default_set=False)
    bpy.ops.import_scene.gltf(filepath=str(KAYKIT_CLIPS))
    takes = {a.name.rsplit("|", 1)[-1].removesuffix("_Rig_Medium"): tuple(a.frame_range) for a in bpy.data.actions}
    assert {"Running_A", "Jump_Full_Long", "Walking_A"} <= set(takes)
    longest = max(takes, key=lambda t: takes[t][1] - takes[t][0])
    rows = {}
    for take in ("Running_A", None, "Nope"):
        report = tmp_path / f"{take}.json"
        extra = ("--take", take) if take else ()
        code, _, err = run(cli, capsys, "retarget", character, "--target", "Hero", "--source-file", KAYKIT_CLIPS,
                           *extra, "--jobs", 1, "--output", tmp_path / f"{take}.blend", "--report", report, "--quiet")
        rows[take] = (code, json.loads(report.read_text())["rows"][0])
    for take, expected in (("Running_A", "Running_A"), (None, longest)):
        row = rows[take][1]
        assert row["status"] == "done", row["reason"]
        assert row["action"] == "kaykit_Med_MovementBasic" + (f"_{take}" if take else "")
        start, end = takes[expected]
        assert row["frame_start"] == 1 and row["frames"] == int(np.floor(1 + end - start)), (take, row)
    code, row = rows["Nope"]
    assert code != 0 and row["status"] == "failed"
    assert row["reason"] == (f"kaykit_Med_MovementBasic.glb has no take 'Nope' (its takes: "
                             f"{', '.join(sorted(takes))})")

    # The run's legs, in the written file, point where the clip's do (the clip's first key on frame 1).
    reopen(tmp_path / "Running_A.blend")
    hero = bpy.data.objects["Hero"]
    assign_action(hero, bpy.data.actions[rows["Running_A"][1]["action"]])
    frames = np.arange(1, rows["Running_A"][1]["frames"] + 1, dtype=float)
    result = _leg_directions(hero, ["thigh.L", "shin.L", "foot.L"], frames)
    bpy.ops.import_scene.gltf(filepath=str(KAYKIT_CLIPS))
    clip = next(ob for ob in bpy.data.objects if ob.type == 'ARMATURE' and ob is not hero)
    run_action = next(a for a in bpy.data.actions if "Rig_Medium|Running_A" in a.name)
    assign_action(clip, run_action)
    source = _leg_directions(clip, ["upperleg.l", "lowerleg.l", "foot.l"], frames - 1.0 + run_action.frame_range[0])
    angles = np.degrees(np.arccos(np.clip(np.sum(result * source, axis=-1), -1.0, 1.0)))
    swing = np.degrees(np.arccos(np.clip(np.sum(source[1:] * source[:-1], axis=-1), -1.0, 1.0))).sum(axis=0)
    assert swing.min() > 60.0  # the clip's legs do swing: a still result would fail below
    assert np.median(angles) < 2.0, np.round(angles, 1)  # measured 0.23 (9.1 before the pelvis turned as its hips)
