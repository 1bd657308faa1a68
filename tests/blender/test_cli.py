"""The command line (fullbody_adjust.cli) through the bpy module, on the sample scenes of sample_scenes/.

The bpy module does not dispatch `blender -c`, so the tests call the command function (cli.main) with the
arguments `blender -b FILE -c fullbody_adjust ...` would pass, reopen what it wrote, and check the input file's
bytes and modification time did not change. One test runs `python -m fullbody_adjust` in a subprocess.
"""

import importlib
import json
import os
from pathlib import Path
import shutil
import subprocess
import sys

import bpy
import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[2]
SAMPLES = REPO / "sample_scenes"
ADJUST_SAMPLES = {"reach_near_far": "Character", "arm_obstacles": "Character", "captured_pose": "Actor"}


def sample(tmp_path, name):
    """A copy of sample_scenes/<name>.blend in tmp_path (the copy is the run's input)."""
    path = tmp_path / f"{name}.blend"
    shutil.copyfile(SAMPLES / f"{name}.blend", path)
    return path


class Untouched:
    """Remembers a file's bytes and modification time."""

    def __init__(self, path):
        self.path = Path(path)
        self.data = self.path.read_bytes()
        self.mtime = self.path.stat().st_mtime_ns

    def check(self):
        assert self.path.stat().st_mtime_ns == self.mtime
        assert self.path.read_bytes() == self.data


def run(cli, capsys, *argv):
    """(exit code, stdout, stderr) of `... -c fullbody_adjust ARGV`."""
    code = cli.main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def reopen(path):
    bpy.ops.wm.open_mainfile(filepath=str(path), load_ui=False)


def save_with_twin(path, name, twin_name):
    """The .blend at ``path`` saved again with a copy of object ``name`` named ``twin_name`` beside it."""
    reopen(path)
    twin = bpy.data.objects[name].copy()
    twin.name = twin_name
    bpy.context.scene.collection.objects.link(twin)
    bpy.ops.wm.save_as_mainfile(filepath=str(path))


def effector_and_target(arm_name, effector, frame):
    """World position of an effector joint (head of the bone mapped to it) and of its target, at ``frame``."""
    obj = bpy.data.objects[arm_name]
    bpy.context.scene.frame_set(frame)
    bone = [item.bone for item in obj.fullbody_adjust.bone_map if item.group == effector][-1]
    slot = [s for s in obj.fullbody_adjust.targets if s.effector == effector][0]
    head = np.array(obj.matrix_world @ obj.pose.bones[bone].head)
    return head, np.array(slot.target.matrix_world.translation)


def keyed_values(action):
    """{(data path, index): (frames, values)} of every F-Curve of ``action`` (any Blender version)."""
    if hasattr(action, "fcurves") and bpy.app.version < (5, 0, 0) and not getattr(action, "is_action_layered",
                                                                                      False):
        curves = list(action.fcurves)
    else:
        curves = [fc for layer in action.layers for strip in layer.strips for bag in strip.channelbags
                  for fc in bag.fcurves]
    out = {}
    for fc in curves:
        co = np.empty(2 * len(fc.keyframe_points), dtype=np.float32)
        fc.keyframe_points.foreach_get("co", co)
        out[(fc.data_path, fc.array_index)] = co.reshape(-1, 2).T.copy()
    return out


def expected_exit_code(report):
    missed = report["tasks"]["missed_within_reach"] > 0
    not_held = any(f["not_held_frames"] for f in (report.get("contacts") or {}).get("effectors", {}).values())
    return 1 if missed or not_held or (report["penetrations"] or {}).get("frames") else 0


# --- help and arguments -------------------------------------------------------------------------------------

def test_help_explains_every_option(cli, capsys):
    parser = cli.build_parser()
    code, out, _ = run(cli, capsys, "--help")
    assert code == 0 and "adjust" in out and "retarget" in out and "exit codes" in out
    subparsers = next(a for a in parser._actions if a.dest == "subcommand")
    for name, sub in subparsers.choices.items():
        code, out, _ = run(cli, capsys, name, "--help")
        assert code == 0
        for action in sub._actions:
            for option in action.option_strings:
                assert option in out, (name, option)
            assert action.help, (name, action.dest)  # every option says what it does


@pytest.mark.parametrize("argv, words", [
    ([], "choose a subcommand"),
    (["walk"], "invalid choice"),
    (["adjust", "FILE", "--variant", "best"], "invalid choice"),
    (["adjust", "FILE", "--margin", "-1"], "must be >= 0"),
    (["adjust", "FILE", "--max-iterations", "0"], "must be >= 1"),
    (["adjust", "FILE", "--frame-start", "one"], "invalid int value"),
    (["adjust", "FILE", "--frobnicate"], "unrecognized arguments"),
    (["retarget", "FILE", "--target", "Large"], "--source"),
    (["retarget", "FILE", "--source", "Source", "--target", "Large", "--contacts", "object"], "exactly one"),
    (["retarget", "FILE", "--source", "Source", "--target", "Large", "--contacts", "wall"], "'ground' or 'object"),
])
def test_bad_arguments_exit_2_with_one_line(cli, capsys, tmp_path, argv, words):
    path = sample(tmp_path, "arm_obstacles")
    before = Untouched(path)
    argv = [str(path) if a == "FILE" else a for a in argv]
    code, out, err = run(cli, capsys, *argv)
    assert code == 2
    assert len(err.strip().splitlines()) == 1 and words in err
    before.check()


# --- adjust ---------------------------------------------------------------------------------------------------

def test_adjust_writes_blend_report_and_preview_and_leaves_the_input(cli, capsys, tmp_path):
    path = sample(tmp_path, "reach_near_far")
    before = Untouched(path)
    out_blend, report_path, png = tmp_path / "out.blend", tmp_path / "report.json", tmp_path / "preview.png"
    code, out, err = run(cli, capsys, "adjust", path, "--frame-start", 18, "--frame-end", 22, "--output", out_blend,
                         "--report", report_path, "--preview", png, "--preview-frames", 2)
    before.check()
    report = json.loads(report_path.read_text())
    assert code == expected_exit_code(report)
    assert "adjust 'Character': 5 frames" in out and f"saved {out_blend}" in out
    assert "frames/s" in err  # the progress line (stderr is not a terminal here: whole lines)
    assert report["command"] == "adjust" and report["armature"] == "Character"
    assert report["frames"] == {"start": 18, "end": 22, "count": 5}
    assert report["frames_per_second"] == pytest.approx(5 / report["seconds"])
    assert report["output"] == str(out_blend)

    # The saved file holds the adjusted motion: the effectors are where the report says, frame by frame.
    reopen(out_blend)
    for effector in ("hand.R", "foot.L", "foot.R"):
        errors = [np.linalg.norm(np.subtract(*effector_and_target("Character", effector, f))) for f in range(18, 23)]
        stats = report["reach_error"][effector]
        reported = [s["max"] for s in stats.values() if s["max"] is not None]
        assert max(errors) == pytest.approx(max(reported), abs=2e-4)  # keys are stored as float32
    action = bpy.data.objects["Character"].animation_data.action
    assert action.name == report["action"]
    keyed_frames = {float(f) for frames, _ in keyed_values(action).values() for f in frames}
    assert keyed_frames == {18.0, 19.0, 20.0, 21.0, 22.0}

    # The picture: a PNG of the layout's size.
    data = png.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    width, height = int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")
    assert width >= 600 and height > 600


def test_new_action_keeps_the_original_motion(cli, capsys, tmp_path):
    path = sample(tmp_path, "captured_pose")
    reopen(path)
    original = keyed_values(bpy.data.actions["ActorMotion"])
    out_blend = tmp_path / "out.blend"
    code, out, err = run(cli, capsys, "adjust", path, "--frame-start", 2, "--frame-end", 3, "--new-action",
                         "Adjusted", "--output", out_blend, "--quiet")
    assert code in (0, 1) and err.count("\n") <= 1
    reopen(out_blend)
    actor = bpy.data.objects["Actor"]
    assert actor.animation_data.action.name == "Adjusted"
    kept = bpy.data.actions["ActorMotion"]
    assert kept.use_fake_user
    assert keyed_values(kept).keys() == original.keys()
    for key, (frames, values) in keyed_values(kept).items():
        assert np.array_equal(frames, original[key][0]) and np.array_equal(values, original[key][1]), key
    changed = keyed_values(actor.animation_data.action)
    for key in changed.keys() - original.keys():  # channels keyed afresh: only on the adjusted frames
        assert list(changed[key][0]) == [2.0, 3.0], key
    moved = [key for key in original if not np.allclose(changed[key][1][1:3], original[key][1][1:3], atol=1e-6)]
    assert moved  # the new action differs on the adjusted frames...
    for key in moved:  # ...and only there
        assert np.array_equal(changed[key][1][3:], original[key][1][3:])
        assert changed[key][1][0] == original[key][1][0]


def test_adjust_in_place_keys_the_armatures_action(cli, capsys, tmp_path):
    path = sample(tmp_path, "captured_pose")
    reopen(path)
    original = keyed_values(bpy.data.actions["ActorMotion"])
    out_blend = tmp_path / "out.blend"
    code, _, _ = run(cli, capsys, "adjust", path, "--armature", "Actor", "--frame-start", 5, "--frame-end", 5,
                     "--variant", "weighted", "--margin", 0.02, "--no-limits", "--output", out_blend, "--quiet",
                     "--report", tmp_path / "r.json")
    report = json.loads((tmp_path / "r.json").read_text())
    assert code == expected_exit_code(report)
    assert report["settings"]["variant"] == "WEIGHTED" and report["settings"]["margin"] == 0.02
    assert report["settings"]["use_joint_limits"] is False
    assert report["action"] == report["original_action"] == "ActorMotion"
    reopen(out_blend)
    assert bpy.data.objects["Actor"].animation_data.action.name == "ActorMotion"
    assert "Adjusted" not in bpy.data.actions
    after = keyed_values(bpy.data.actions["ActorMotion"])
    assert any(not np.allclose(after[key][1][4], original[key][1][4], atol=1e-6) for key in original)
    for key in original:  # frame 5 is the fifth key; every other key is as it was
        others = np.arange(len(original[key][1])) != 4
        assert np.array_equal(after[key][1][others], original[key][1][others]), key


def test_overwrite_replaces_the_input_only_when_asked(cli, capsys, tmp_path):
    path = sample(tmp_path, "arm_obstacles")
    before = Untouched(path)
    code, _, err = run(cli, capsys, "adjust", path, "--frame-start", 1, "--frame-end", 2, "--output", path)
    assert code == 2 and "--overwrite" in err
    before.check()
    code, out, _ = run(cli, capsys, "adjust", path, "--frame-start", 1, "--frame-end", 2, "--overwrite", "--quiet")
    assert code in (0, 1) and f"saved {path}" in out
    assert path.read_bytes() != before.data
    reopen(path)
    assert bpy.data.objects["Character"].animation_data.action is not None


def test_without_output_nothing_is_saved(cli, capsys, tmp_path):
    path = sample(tmp_path, "arm_obstacles")
    before = Untouched(path)
    code, out, _ = run(cli, capsys, "adjust", path, "--frame-start", 1, "--frame-end", 1, "--quiet")
    assert code in (0, 1) and "not saved" in out
    before.check()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["arm_obstacles.blend"]


def _unmappable_scene(tmp_path):
    """A scene whose only armature is a two-bone chain with a target: it cannot be mapped."""
    bpy.ops.wm.read_homefile(use_empty=True)
    data = bpy.data.armatures.new("Stick")
    obj = bpy.data.objects.new("Stick", data)
    bpy.context.scene.collection.objects.link(obj)
    bpy.context.view_layer.objects.active = obj
    bpy.ops.object.mode_set(mode='EDIT')
    a = data.edit_bones.new("a")
    a.head, a.tail = (0, 0, 0), (0, 0, 1)
    b = data.edit_bones.new("b")
    b.head, b.tail, b.parent = (0, 0, 1), (0, 0, 2), a
    bpy.ops.object.mode_set(mode='OBJECT')
    empty = bpy.data.objects.new("Goal", None)
    bpy.context.scene.collection.objects.link(empty)
    slot = obj.fullbody_adjust.targets.add()
    slot.effector, slot.target, slot.enabled = 'hand.L', empty, True
    path = tmp_path / "stick.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(path))
    return path


def _typed_map_scene(tmp_path):
    """The basic metarig with targets, its bone map then edited by hand to name a bone it does not have."""
    bpy.ops.wm.read_homefile(use_empty=True)
    bpy.ops.preferences.addon_enable(module="rigify")
    bpy.ops.object.armature_basic_human_metarig_add()
    obj = bpy.context.active_object
    bpy.ops.fullbody_adjust.create_targets()
    next(item for item in obj.fullbody_adjust.bone_map if item.bone == "forearm.L").bone = "lower_arm.L"
    path = tmp_path / "typed.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(path))
    return path


@pytest.mark.parametrize("case, extra, words", [
    ("missing file", [], "no such file"),
    ("unknown armature", ["--armature", "Nobody"], "no object named 'Nobody'"),
    ("not an armature", ["--armature", "Blue"], "not an armature"),
    ("range outside the action", ["--armature", "Actor", "--frame-start", 1, "--frame-end", 40], "outside action"),
    ("empty range", ["--frame-start", 5, "--frame-end", 2], "empty"),
    ("output folder missing", ["--output", "{tmp}/no/such/folder/out.blend"], "does not exist"),
    ("output not a .blend", ["--output", "{tmp}/out.txt"], "must end in .blend"),
    ("report over the input", ["--report", "{input}"], "would overwrite the input"),
    ("output folder read-only", ["--output", "{tmp}/locked/out.blend"], "not writable"),
    ("unmappable rig", [], "mapp"),
    ("typed map that does not fit", [], "typed on 'metarig' does not fit it: arm.L: no bone 'lower_arm.L'"),
    ("not a blend file", [], "Cannot open"),
])
def test_bad_input_exits_2_and_leaves_the_input(cli, capsys, tmp_path, case, extra, words):
    if case == "unmappable rig":
        path = _unmappable_scene(tmp_path)
    elif case == "typed map that does not fit":
        path = _typed_map_scene(tmp_path)
    elif case == "not a blend file":
        path = tmp_path / "notes.blend"
        path.write_text("not a blend file\n")
    else:
        path = sample(tmp_path, "captured_pose" if "action" in case else "arm_obstacles")
    if case == "output folder read-only":
        (tmp_path / "locked").mkdir()
        os.chmod(tmp_path / "locked", 0o500)
        if os.access(tmp_path / "locked", os.W_OK):  # root ignores permissions
            pytest.skip("running as a user who can write anywhere")
    before = Untouched(path)
    given = tmp_path / "missing.blend" if case == "missing file" else path
    argv = [str(a).format(tmp=tmp_path, input=path) for a in extra]
    code, out, err = run(cli, capsys, "adjust", given, *argv, "--quiet")
    assert code == 2, (out, err)
    assert len(err.strip().splitlines()) == 1 and words.lower() in err.lower(), err
    assert err.startswith("fullbody_adjust adjust: error: ")
    before.check()
    assert not any(p.suffix in (".png", ".json") or p.name == "out.blend" for p in tmp_path.rglob("*"))


def test_default_armature_must_be_unambiguous(cli, capsys, tmp_path):
    path = sample(tmp_path, "arm_obstacles")
    save_with_twin(path, "Character", "Twin")
    before = Untouched(path)
    code, _, err = run(cli, capsys, "adjust", path, "--quiet")
    assert code == 2 and "Several armatures have targets" in err and "--armature" in err
    before.check()
    code, out, _ = run(cli, capsys, "adjust", path, "--armature", "Twin", "--frame-start", 1, "--frame-end", 1,
                       "--quiet")
    assert code in (0, 1) and "adjust 'Twin'" in out


def test_the_file_blender_opened_is_used_when_none_is_given(cli, capsys, tmp_path):
    # Under `blender -b FILE.blend -c fullbody_adjust adjust ...` Blender has opened FILE already.
    path = sample(tmp_path, "arm_obstacles")
    reopen(path)
    code, out, _ = run(cli, capsys, "adjust", "--frame-start", 1, "--frame-end", 1, "--output",
                       tmp_path / "out.blend", "--quiet")
    assert code in (0, 1) and (tmp_path / "out.blend").exists()
    bpy.ops.wm.read_homefile(use_empty=True)
    code, _, err = run(cli, capsys, "adjust", "--quiet")
    assert code == 2 and "give FILE.blend" in err


@pytest.mark.parametrize("name", sorted(ADJUST_SAMPLES))
def test_every_adjust_sample_opens_and_runs(cli, capsys, tmp_path, name):
    path = sample(tmp_path, name)
    code, out, _ = run(cli, capsys, "adjust", path, "--frame-start", 1, "--frame-end", 2, "--quiet", "--report",
                       tmp_path / "r.json")
    report = json.loads((tmp_path / "r.json").read_text())
    assert code == expected_exit_code(report)
    assert report["armature"] == ADJUST_SAMPLES[name] and report["tasks"]["total"] > 0


def test_python_m_runs_the_same_command(tmp_path):
    path = sample(tmp_path, "arm_obstacles")
    before = Untouched(path)
    out_blend, report_path = tmp_path / "out.blend", tmp_path / "r.json"
    env = dict(os.environ, BLENDER_USER_RESOURCES=str(tmp_path / "user"))
    done = subprocess.run([sys.executable, "-m", "fullbody_adjust", "adjust", str(path), "--frame-start", "1",
                           "--frame-end", "2", "--output", str(out_blend), "--report", str(report_path), "--quiet"],
                          cwd=REPO, env=env, capture_output=True, text=True, timeout=120)
    report = json.loads(report_path.read_text())
    assert done.returncode == expected_exit_code(report), done.stderr
    assert "adjust 'Character': 2 frames" in done.stdout
    before.check()
    reopen(out_blend)
    assert bpy.data.objects["Character"].animation_data.action is not None
    bad = subprocess.run([sys.executable, "-m", "fullbody_adjust", "adjust", str(tmp_path / "none.blend")],
                         cwd=REPO, env=env, capture_output=True, text=True, timeout=120)
    assert bad.returncode == 2 and bad.stderr.strip().splitlines()[-1].endswith(f"no such file: {tmp_path}/none.blend")


def test_cli_command_registers_and_unregisters(cli):
    # Enabling the extension registered `blender -c fullbody_adjust`; its module undoes and redoes that.
    assert cli._handle is not None
    cli.unregister()
    try:
        assert cli._handle is None
    finally:
        cli.register()
    assert cli._handle is not None


# --- retarget -------------------------------------------------------------------------------------------------

def test_retarget_sample_has_mappable_armatures_and_an_object(tmp_path, extension_module_name):
    batch = importlib.import_module(f"{extension_module_name}.bridge.files")
    reopen(sample(tmp_path, "retarget_cmu"))
    source, large, small = (bpy.data.objects[n] for n in ("Source", "Large", "Small"))
    for obj in (source, large, small):
        batch.check_mappable(obj, "--target")
    assert source.animation_data.action is not None and large.animation_data is None
    ratio = {o.name: o.data.bones["LeftUpLeg"].length / source.data.bones["LeftUpLeg"].length for o in (large, small)}
    assert ratio == {"Large": pytest.approx(1.2), "Small": pytest.approx(0.85)}
    assert bpy.data.objects["Ball"].type == 'MESH'


@pytest.mark.parametrize("extra, words", [
    (["--source", "Nobody", "--target", "Large"], "no object named 'Nobody'"),
    (["--source", "Source", "--target", "Source"], "the same armature"),
    (["--source", "Source", "--target", "Ball"], "not an armature"),
    (["--source", "Source", "--target", "Large", "--contacts", "object", "Cup"], "no object named 'Cup'"),
    (["--source", "Source", "--target", "Large", "--frame-end", 500], "outside action"),
])
def test_retarget_bad_input_exits_2(cli, capsys, tmp_path, extra, words):
    path = sample(tmp_path, "retarget_cmu")
    before = Untouched(path)
    code, _, err = run(cli, capsys, "retarget", path, *extra, "--output", tmp_path / "out.blend", "--quiet")
    assert code == 2 and len(err.strip().splitlines()) == 1 and words in err, err
    before.check()
    assert not (tmp_path / "out.blend").exists()


def test_retarget_of_an_unmappable_target_exits_2(cli, capsys, tmp_path):
    path = _unmappable_scene(tmp_path)
    save_with_twin(path, "Stick", "Stick2")
    before = Untouched(path)
    code, _, err = run(cli, capsys, "retarget", path, "--source", "Stick", "--target", "Stick2", "--quiet")
    assert code == 2 and "--source 'Stick' cannot be mapped" in err
    before.check()


def test_contacts_may_be_given_more_than_once(cli):
    args = cli.build_parser().parse_args(["retarget", "FILE", "--source", "S", "--target", "T", "--contacts", "ground",
                                          "--contacts", "object", "Bar", "--contacts", "object", "Step"])
    assert args.contacts == [("ground", None), ("object", "Bar"), ("object", "Step")]


@pytest.mark.parametrize("target, contacts", [("Large", ["object", "Ball"]), ("Small", ["ground"])])
def test_retarget_writes_the_targets_motion(cli, capsys, tmp_path, target, contacts):
    path = sample(tmp_path, "retarget_cmu")
    before = Untouched(path)
    out_blend, report_path, png = tmp_path / "out.blend", tmp_path / "r.json", tmp_path / "p.png"
    code, out, err = run(cli, capsys, "retarget", path, "--source", "Source", "--target", target, "--frame-start", 20,
                         "--frame-end", 22, "--contacts", *contacts, "--new-action", "Carried", "--output",
                         out_blend, "--report", report_path, "--preview", png, "--quiet")
    before.check()
    report = json.loads(report_path.read_text())
    assert code == expected_exit_code(report)
    assert report["source"] == "Source" and report["target"] == target and report["frames"]["count"] == 3
    assert report["contacts"]["contacts"] == [" ".join(contacts)] and report["action"] == "Carried"
    assert set(report["contacts"]["effectors"]) == {"hand.L", "hand.R", "foot.L", "foot.R"}
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    reopen(out_blend)
    action = bpy.data.objects[target].animation_data.action
    assert action.name == "Carried"
    assert {float(f) for frames, _ in keyed_values(action).values() for f in frames} == {20.0, 21.0, 22.0}


@pytest.mark.parametrize("extra, named", [(["--format", "fbx"], "--format"), (["--jobs", "2"], "--jobs"),
                                          (["--scheduler", "tcp://127.0.0.1:1", "--take", "Run"], "--take"),
                                          (["--output-dir", "out", "--armature-only"], "--armature-only")])
def test_clip_file_options_given_with_source_are_one_line_and_the_file_untouched(cli, capsys, tmp_path, extra,
                                                                                  named):
    """Options that act on clips from files only would do nothing to a retarget of an armature in the file."""
    path = sample(tmp_path, "retarget_cmu")
    untouched = Untouched(path)
    code, out, err = run(cli, capsys, "retarget", path, "--source", "Source", "--target", "Large", "--overwrite",
                         *extra)
    assert code == 2 and len(err.strip().splitlines()) == 1 and named in err and "--source-file" in err, err
    untouched.check()
    assert not (tmp_path / "out").exists()


def test_the_clip_file_options_listed_have_the_parsers_defaults(cli):
    """FILE_ONLY's defaults are the parser's: a retarget of an armature in the file given none of them runs."""
    args = cli.build_parser().parse_args(["retarget", "F", "--source", "S", "--target", "T"])
    assert cli.parser.file_only_options(args) == []
    clip_args = cli.build_parser().parse_args(["retarget", "F", "--source-file", "c.bvh", "--target", "T"])
    assert {option: getattr(clip_args, name) for option, (name, _) in cli.parser.FILE_ONLY.items()} == {
        option: default for option, (_, default) in cli.parser.FILE_ONLY.items()}
