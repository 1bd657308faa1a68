"""`retarget --source-file ... --output-dir DIR --format fbx|glb`: each clip written through Blender's own
exporter, imported back into a fresh file in a fresh process (tests/helpers/joint_positions.py), and its world
joint positions compared frame by frame with the .blend the same batch writes."""

import importlib
import json
from pathlib import Path
import subprocess
import sys

import bpy
import numpy as np
import pytest

from tests.helpers.bvh import MOCAP_DIR, cut_bvh

from .test_cli import run

HELPER = Path(__file__).resolve().parents[1] / "helpers" / "joint_positions.py"
TOLERANCE = 1e-3  # m: the goal for a re-imported file


@pytest.fixture
def clips(tmp_path):
    folder = tmp_path / "clips"
    folder.mkdir()
    cut_bvh(MOCAP_DIR / "cmu_07_01_walk.bvh", folder / "walk.bvh", 1, 120)
    cut_bvh(MOCAP_DIR / "cmu_02_04_jump.bvh", folder / "jump.bvh", 1, 100)
    return folder


@pytest.fixture
def character(tmp_path, rig):
    """The Rigify basic metarig 'Hero' (turned and moved off the origin, so axes and units show) with a box
    skinned to its spine, saved."""
    rig.name = "Hero"
    rig.location = (0.4, -0.3, 0.0)
    rig.rotation_euler = (0.0, 0.0, 0.5)
    bpy.ops.mesh.primitive_cube_add(size=0.2, location=(0.4, -0.3, 1.2))
    body = bpy.context.object
    body.name = "Body"
    group = body.vertex_groups.new(name="spine.003")
    group.add(range(len(body.data.vertices)), 1.0, 'REPLACE')
    body.modifiers.new("Armature", 'ARMATURE').object = rig
    body.parent = rig
    body.matrix_parent_inverse = rig.matrix_world.inverted()
    path = tmp_path / "hero.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(path))
    bpy.ops.wm.read_homefile(use_empty=True)
    return path


def joints_of(path, tmp_path):
    """What tests/helpers/joint_positions.py reads of ``path`` in a fresh process."""
    out = tmp_path / f"{Path(path).name}.json"
    done = subprocess.run([sys.executable, str(HELPER), str(path), str(out)], capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    return json.loads(out.read_text())


def batch(cli, capsys, character, clips, folder, *extra, expected=2):
    folder.mkdir(parents=True)
    code, _, err = run(cli, capsys, "retarget", character, "--target", "Hero", "--source-file", clips, "--jobs", 2,
                       "--output-dir", folder, "--quiet", "--report", folder / "report.json", *extra)
    report = json.loads((folder / "report.json").read_text())
    assert [row["status"] for row in report["rows"]] == ["done"] * expected, err
    return code, report


@pytest.mark.parametrize("file_format", ["fbx", "glb"])
def test_engine_files_carry_the_blend_results_motion_within_a_millimetre(cli, capsys, tmp_path, clips, character,
                                                                        file_format):
    blend_code, blend_report = batch(cli, capsys, character, clips, tmp_path / "blend")
    code, report = batch(cli, capsys, character, clips, tmp_path / file_format, "--format", file_format)
    assert code == blend_code
    assert sorted(p.name for p in (tmp_path / file_format).iterdir()) == sorted(
        ["report.json", "report.csv", f"jump.{file_format}", f"walk.{file_format}"])
    for row, blend_row in zip(report["rows"], blend_report["rows"]):
        assert row["output"] == str(tmp_path / file_format / f"{row['name']}.{file_format}")
        assert (row["frames"], row["frame_start"], row["frame_end"]) == (
            blend_row["frames"], blend_row["frame_start"], blend_row["frame_end"])

        solved = joints_of(tmp_path / "blend" / f"{row['name']}.blend", tmp_path)
        written = joints_of(row["output"], tmp_path)
        assert solved["frames"] == list(range(row["frame_start"], row["frame_end"] + 1))
        assert len(written["frames"]) == row["frames"]  # one key per frame, from the clip's first
        # The skeleton an engine skins with: every deforming bone (and no other), the mesh bound to it.
        assert sorted(written["joints"]) == solved["deform"]
        assert written["meshes"] == ["Body"]
        # The engine's animation is named after the clip: FBX's take, glTF's animation (imported as
        # '<armature>|<take>', '<animation>' or, by Blender 4.2's glTF importer, '<animation>_<armature>').
        suffix = f"_{written['armature']}"
        assert [name.split("|")[-1].removesuffix(suffix) for name in written["actions"]] == [row["action"]]
        moved = 0.0
        for bone in solved["deform"]:
            expected = np.array(solved["joints"][bone])
            got = np.array(written["joints"][bone])
            assert np.abs(got - expected).max() < TOLERANCE, bone
            moved = max(moved, float(np.ptp(expected, axis=0).max()))
        assert moved > 0.3  # the motion itself is compared, not a still pose


def test_armature_only_leaves_the_meshes_out(cli, capsys, tmp_path, clips, character):
    folder = tmp_path / "fbx"
    batch(cli, capsys, character, clips, folder, "--format", "fbx", "--armature-only")
    written = joints_of(folder / "jump.fbx", tmp_path)
    assert written["meshes"] == [] and written["armature"] == "Hero"
    assert written["actions"] and len(written["frames"]) > 1


@pytest.mark.parametrize("extra, words", [
    (("--format", "fbx"), "--format fbx writes one file per clip: give --output-dir"),
    (("--armature-only", "--output-dir", "DIR"), "--armature-only leaves the meshes out of --format fbx or glb"),
    (("--format", "obj", "--output-dir", "DIR"), "invalid choice: 'obj'"),
])
def test_bad_format_options_are_one_line(cli, capsys, tmp_path, clips, character, extra, words):
    extra = [str(tmp_path / "out") if e == "DIR" else e for e in extra]
    code, out, err = run(cli, capsys, "retarget", character, "--target", "Hero", "--source-file", clips, *extra)
    assert code == 2 and words in err and len(err.strip().splitlines()) == 1, err
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("name", ["kenney", "metarig_cm_units"])
@pytest.mark.parametrize("file_format", ["fbx", "glb"])
def test_characters_users_bring_come_back_in_metres(cli, capsys, tmp_path, clips, name, file_format):
    """Kenney's FBX character (its meshes skinned to a Mixamo-named skeleton) and a metarig with a body mesh in a
    centimetre scene (unit scale 0.01): the engine file's joints, re-imported into a metre scene, are where the
    .blend's are, in metres."""
    from tests.helpers import real_rigs

    rig = real_rigs.load(name)
    rig.armature.name = "Hero"
    meshes = sorted(m.name for m in rig.meshes)
    character = tmp_path / "hero.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(character))
    bpy.ops.wm.read_homefile(use_empty=True)
    (clips / "walk.bvh").unlink()
    batch(cli, capsys, character, clips, tmp_path / "blend", expected=1)
    batch(cli, capsys, character, clips, tmp_path / file_format, "--format", file_format, expected=1)
    solved = joints_of(tmp_path / "blend" / "jump.blend", tmp_path)
    written = joints_of(tmp_path / file_format / f"jump.{file_format}", tmp_path)
    assert len(written["frames"]) == len(solved["frames"])
    assert written["meshes"] == meshes != []
    bones = [bone for bone in solved["deform"] if bone in written["joints"]]
    assert len(bones) == len(solved["deform"])
    for bone in bones:
        assert np.abs(np.array(written["joints"][bone]) - np.array(solved["joints"][bone])).max() < TOLERANCE, bone


@pytest.mark.parametrize("file_format", ["fbx", "glb"])
def test_writing_an_engine_file_leaves_the_scene_as_it_was(tmp_path, rig, extension_module_name, file_format):
    export = importlib.import_module(f"{extension_module_name}.bridge.retarget.export")
    scene = bpy.context.scene
    scene.unit_settings.scale_length = 0.01  # the glTF path parents the character to a root in metres, then undoes it
    scene.frame_start, scene.frame_end = 3, 7
    rig.matrix_parent_inverse[0][3] = 0.5  # unused without a parent, but the user's: kept
    action = bpy.data.actions.new("clip")
    rig.animation_data_create().action = action
    rig.keyframe_insert("location", frame=1)
    rig.keyframe_insert("location", frame=40)
    other = bpy.data.objects.new("Other", None)
    scene.collection.objects.link(other)
    other.select_set(True)
    rig.select_set(False)
    bpy.context.view_layer.objects.active = other
    objects = sorted(ob.name for ob in bpy.data.objects)
    export.write_clip(bpy.context, rig, action, tmp_path / f"clip.{file_format}", file_format)
    assert (tmp_path / f"clip.{file_format}").stat().st_size > 1000
    assert (scene.frame_start, scene.frame_end) == (3, 7)
    assert sorted(ob.name for ob in bpy.data.objects) == objects and rig.parent is None
    assert rig.matrix_parent_inverse[0][3] == 0.5
    assert [ob.name for ob in bpy.context.selected_objects] == ["Other"]
    assert bpy.context.view_layer.objects.active == other
