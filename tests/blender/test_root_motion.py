"""``retarget --root-motion bone|object|in-place`` measured on the written files against the default (travel on the
hips), from Blender's own evaluation: every frame set, every bone's evaluated world matrix (pose bone matrix
under the evaluated object matrix), nothing taken from the solver.

- bone, object: every bone of the default result at the same world position on every frame (0.1 mm); the hips
  carry no horizontal travel and no turn relative to the root (the root bone's world matrix, or the object's);
  planted feet (tests/helpers/rig_measures.plants on the result's own ankles and toes) slide < 1 mm (p95).
- in-place: the hips stay over one place (0.1 mm); the motion removed is, on each frame, one turn about the
  vertical and one horizontal shift of the whole body (fitted here from the two results' bones; no bone off it by
  more than 0.1 mm, no tilt, no vertical shift); with it put back, as an engine moving the character by its root
  motion does, planted feet slide < 1 mm (p95) relative to the floor.
"""

import importlib
from pathlib import Path
import shutil

import bpy
import numpy as np
import pytest

from tests.helpers import rig_measures as rm
from tests.helpers.blender_data import bulk, evaluated

REPO = Path(__file__).resolve().parents[2]
SAMPLE = REPO / "sample_scenes" / "retarget_cmu.blend"
TARGET = "Large"
FRAMES = (1, 60)
MODES = {"hips": (), "bone": ("--root-bone", "root"), "object": (), "in-place": ()}
FEET = {"L": ("LeftFoot", "LeftToeBase"), "R": ("RightFoot", "RightToeBase")}
MM = 1e-3  # the scene is in metres


@pytest.fixture(scope="module")
def cli(extension_module_name):
    return importlib.import_module(f"{extension_module_name}.cli")


def run(cli, capsys, *argv):
    code = cli.main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def world_matrices(obj):
    """{bone: (4,4)} evaluated world matrices of every bone, and the object's (4,4)."""
    ev = evaluated(obj)
    world = np.array(ev.matrix_world, dtype=np.float64)
    pose = bulk(ev.pose.bones, "matrix", (4, 4)).transpose(0, 2, 1)
    return {pb.name: world @ m for pb, m in zip(ev.pose.bones, pose)}, world


def measure(path):
    """{'bones': {name: (F,4,4)}, 'object': (F,4,4)} of the target over FRAMES in the file at ``path``."""
    bpy.ops.wm.open_mainfile(filepath=str(path), load_ui=False)
    obj = bpy.data.objects[TARGET]
    bones, objects = {}, []
    for frame in range(FRAMES[0], FRAMES[1] + 1):
        bpy.context.scene.frame_set(frame)
        matrices, world = world_matrices(obj)
        for name, m in matrices.items():
            bones.setdefault(name, []).append(m)
        objects.append(world)
    rest = {b.name: np.array(b.matrix_local, dtype=np.float64) for b in obj.data.bones}
    return {"bones": {n: np.array(m) for n, m in bones.items()}, "object": np.array(objects), "rest": rest}


@pytest.fixture(scope="module")
def results(cli, tmp_path_factory):
    """Each mode's result, retargeted from the sample's Source onto Large over FRAMES, measured."""
    import _pytest.capture  # noqa: F401  (capsys is function-scoped: read the output with capfd-free calls)
    folder = tmp_path_factory.mktemp("root_motion")
    source = folder / "in.blend"
    shutil.copyfile(SAMPLE, source)
    out = {}
    for mode, extra in MODES.items():
        path = folder / f"{mode}.blend"
        code = cli.main([str(a) for a in ("retarget", source, "--source", "Source", "--target", TARGET,
                                          "--frame-start", FRAMES[0], "--frame-end", FRAMES[1],
                                          "--root-motion", mode, *extra, "--output", path, "--quiet")])
        assert code in (0, 1) and path.exists(), mode
        out[mode] = measure(path)
    return out


def heads(result, names):
    return np.stack([result["bones"][n][:, :3, 3] for n in names], axis=1)  # (F,k,3)


def foot_slides(result):
    """(k,) slide distances (m) of both feet's plants, found on the result's own ankle and toe tracks."""
    fps = bpy.context.scene.render.fps / bpy.context.scene.render.fps_base
    out = []
    for ankle, ball in FEET.values():
        a, b = result["bones"][ankle][:, :3, 3], result["bones"][ball][:, :3, 3]
        planted, which = rm.plants(a, b, fps, 1.0)
        out.append(rm.slides(planted, which, {"ankle": a, "ball": b}))
    return np.concatenate(out), int(sum(len(s) for s in out))


def relative_to(frames, matrices):
    """frames^-1 @ matrices, (F,4,4) each, scale removed from the frames."""
    unit = frames.copy()
    unit[:, :3, :3] /= np.linalg.norm(unit[:, :3, :3], axis=-2, keepdims=True)
    return np.linalg.inv(unit) @ matrices


def unit(m):
    """The rotations (…,3,3) of (…,4,4) matrices, scale removed."""
    return m[..., :3, :3] / np.linalg.norm(m[..., :3, :3], axis=-2, keepdims=True)


def twist_degrees(r):
    """(F,) degrees of the twist about world +Z of rotations (F,3,3): tan(a/2) = (r10 - r01) / (1 + trace)."""
    return np.degrees(2.0 * np.arctan2(r[:, 1, 0] - r[:, 0, 1], 1.0 + np.trace(r, axis1=1, axis2=2)))


def yaw(m):
    """(F,) degrees of the X axis of (F,4,4) matrices about the vertical."""
    x = m[:, :3, 0]
    return np.degrees(np.unwrap(np.arctan2(x[:, 1], x[:, 0])))


def test_default_result_travels_and_turns(results):
    hips = results["hips"]["bones"]["Hips"]
    travel = np.linalg.norm(hips[-1, :2, 3] - hips[0, :2, 3])
    print(f"default: hips travel {travel:.3f} m, yaw range {np.ptp(yaw(hips)):.1f} deg")
    assert travel > 0.1  # the tests below measure something: the sample walks


@pytest.mark.parametrize("mode", ["bone", "object"])
def test_every_bone_where_the_default_puts_it(results, mode):
    names = list(results["hips"]["bones"])
    off = np.linalg.norm(heads(results[mode], names) - heads(results["hips"], names), axis=-1)
    tails = np.linalg.norm(np.stack([results[mode]["bones"][n][:, :3, 1] - results["hips"]["bones"][n][:, :3, 1]
                                     for n in names], axis=1), axis=-1)
    print(f"{mode}: {len(names)} bones x {off.shape[0]} frames, head off max {off.max() / MM:.5f} mm, "
          f"Y axis off max {tails.max():.2e}")
    assert off.max() < 0.1 * MM and tails.max() < 1e-4


@pytest.mark.parametrize("mode", ["bone", "object"])
def test_the_hips_carry_no_travel_and_no_turn(results, mode):
    result = results[mode]
    root = result["bones"]["root"] if mode == "bone" else result["object"]
    hips = relative_to(root, result["bones"]["Hips"])
    drift = np.ptp(hips[:, :3, 3], axis=0)
    world_travel = np.linalg.norm(np.ptp(root[:, :2, 3], axis=0))
    print(f"{mode}: hips relative to the root drift x {drift[0] / MM:.5f} y {drift[1] / MM:.5f} "
          f"z {drift[2] / MM:.2f} mm; root travels {world_travel:.3f} m, turns {np.ptp(yaw(root)):.1f} deg")
    up = 1 if mode == "bone" else 2  # the created root bone points up: its Y axis; the object's Z
    assert np.abs(unit(root)[:, :, up] - (0.0, 0.0, 1.0)).max() < 1e-6  # the root turns about the vertical only
    horizontal = [a for a in range(3) if a != up]
    assert np.ptp(hips[:, horizontal, 3], axis=0).max() < 0.1 * MM
    assert world_travel > 0.1
    # No turn about the vertical relative to the root: the hips' world rotation away from their rest place on
    # the root, root(t) @ rest_root^-1 @ rest_hips, has no twist about +Z (only tilt).
    rest = result["rest"]
    rest_root = rest["root"] if mode == "bone" else np.eye(4)
    on_root = unit(np.linalg.inv(rest_root) @ rest["Hips"])
    away = unit(result["bones"]["Hips"]) @ on_root.T @ np.swapaxes(unit(root), 1, 2)
    twist = twist_degrees(away)
    print(f"{mode}: hips twist about the vertical relative to the root: max {np.abs(twist).max():.2e} deg")
    assert np.abs(twist).max() < 1e-3


@pytest.mark.parametrize("mode", ["hips", "bone", "object"])
def test_planted_feet_hold_in_the_world(results, mode):
    slides, planted = foot_slides(results[mode])
    print(f"{mode}: {planted} planted frames, slide p95 {np.percentile(slides, 95) / MM:.3f} mm, "
          f"max {slides.max() / MM:.3f} mm")
    assert planted >= 10 and np.percentile(slides, 95) < 1.0 * MM


def fit_removed_motion(default, in_place, names):
    """(F,4,4) per frame, the rigid motion taking the in-place bones' heads onto the default's (Kabsch)."""
    a, b = heads(in_place, names), heads(default, names)
    out = np.zeros((len(a), 4, 4))
    for f in range(len(a)):
        ca, cb = a[f].mean(axis=0), b[f].mean(axis=0)
        u, _, vt = np.linalg.svd((a[f] - ca).T @ (b[f] - cb))
        d = np.sign(np.linalg.det(vt.T @ u.T))
        r = vt.T @ np.diag([1.0, 1.0, d]) @ u.T
        out[f, :3, :3], out[f, :3, 3], out[f, 3, 3] = r, cb - r @ ca, 1.0
    return out


def test_in_place_removes_the_travel_and_nothing_else(results):
    default, in_place = results["hips"], results["in-place"]
    names = list(default["bones"])
    hips = in_place["bones"]["Hips"][:, :3, 3]
    removed = fit_removed_motion(default, in_place, names)
    back = np.einsum("fij,fkj->fki", removed[:, :3, :3], heads(in_place, names)) + removed[:, None, :3, 3]
    off = np.linalg.norm(back - heads(default, names), axis=-1)
    tilt = np.degrees(np.arccos(np.clip(removed[:, 2, 2], -1.0, 1.0)))
    print(f"in-place: hips drift x {np.ptp(hips[:, 0]) / MM:.5f} y {np.ptp(hips[:, 1]) / MM:.5f} mm; the removed "
          f"motion: tilt max {tilt.max():.2e} deg, vertical shift max {np.abs(removed[:, 2, 3]).max() / MM:.5f} mm,"
          f" bones off it max {off.max() / MM:.5f} mm")
    assert np.ptp(hips[:, :2], axis=0).max() < 0.1 * MM
    assert tilt.max() < 1e-3 and np.abs(removed[:, 2, 3]).max() < 0.1 * MM and off.max() < 0.1 * MM
    # Put back, the plants hold relative to the floor; in place they slide with the travel removed.
    moved = {"bones": {n: removed @ m for n, m in in_place["bones"].items()}}
    slides, planted = foot_slides(moved)
    raw, _ = foot_slides(in_place)
    print(f"in-place: {planted} planted frames, slide p95 with the removed motion put back "
          f"{np.percentile(slides, 95) / MM:.3f} mm")
    assert planted >= 10 and np.percentile(slides, 95) < 1.0 * MM
