"""The character in the world: armature units and object scale are handled once, at the bridge
(bridge/retarget/read.rig_of: the Rig's world matrix), and the facing comes from the skeleton
(solver/retarget/rig.rest_forward). A source whose armature is a hundredth of the size, scaled up 100 times by
its object, or a target in centimetres scaled by 0.01, retargets exactly as the plain ones, with the figures
reported in world units (metres here); a target turned in its data keeps facing where it faces and walks that
way as the source walks its own way."""

import bpy
import numpy as np
import pytest

from fullbody_adjust.bridge.writing import keyframes
from fullbody_adjust.bridge.retarget import run as retarget
from fullbody_adjust.bridge.reading.pose import read_pose_frames
from tests.helpers.bvh import CMU_SCALE, MOCAP_DIR

from .test_retarget import FRAMES, WALK, add_metarig, enable_addon, select_only


def import_walk(units=1.0):
    """The CMU walk with its armature ``units`` times the size (its rest scaled in the data, its location keys
    with it), its object scaled by 1/units: the same size in the world, as a glTF character 0.115 units tall
    scaled up by its node is. (The BVH importer's own scale would also change the tails it makes up.)"""
    enable_addon("io_anim_bvh")
    bpy.ops.import_anim.bvh(filepath=str(MOCAP_DIR / WALK), global_scale=CMU_SCALE, update_scene_fps=True,
                            update_scene_duration=True)
    obj = bpy.context.active_object
    if units != 1.0:
        select_only(obj)
        obj.scale = (units,) * 3
        bpy.ops.object.transform_apply(location=False, rotation=False, scale=True)
        for fc in keyframes.animating_fcurves(obj):
            if fc.data_path.endswith(".location"):
                for key in fc.keyframe_points:
                    key.co[1] *= units
                    key.handle_left[1] *= units
                    key.handle_right[1] *= units
        obj.scale = (1.0 / units,) * 3
    bpy.context.view_layer.update()
    return obj


def world_heads(obj, frames):
    return read_pose_frames(obj, np.asarray(frames, dtype=float)).heads


def _retarget(source_units, target_units):
    bpy.ops.wm.read_homefile(use_empty=True)
    source = import_walk(source_units)
    target = add_metarig(1.0, location=(1.5, 0.0, 0.0))
    if target_units != 1.0:  # the metarig in other units: its data scaled, its object scaled back
        select_only(target)
        target.scale = (target_units,) * 3
        bpy.ops.object.transform_apply(location=False, rotation=False, scale=True)
        target.scale = (1.0 / target_units,) * 3
        bpy.context.view_layer.update()
    outcome = retarget.retarget(bpy.context, source, target, *FRAMES)
    return outcome, world_heads(target, outcome.frames)


@pytest.mark.parametrize("source_units, target_units", [(0.01, 1.0), (1.0, 100.0), (0.01, 100.0)])
def test_units_and_object_scale_change_nothing_in_the_world(source_units, target_units):
    plain, heads = _retarget(1.0, 1.0)
    other, other_heads = _retarget(source_units, target_units)
    np.testing.assert_allclose(other_heads, heads, atol=1e-4)  # metres (float32 data at other scales)
    assert other.leg_ratio == pytest.approx(plain.leg_ratio, rel=1e-5)
    a, b = plain.contact_report, other.contact_report
    assert b["floor"] == pytest.approx(a["floor"], abs=1e-4)
    for effector, figures in a["effectors"].items():
        got = b["effectors"][effector]
        assert got["frames_below_floor"] == figures["frames_below_floor"]
        assert got["contacts"] == figures["contacts"]
        for key in ("contact_error", "sliding"):
            if figures[key]["max"] is not None:
                assert got[key]["max"] == pytest.approx(figures[key]["max"], abs=1e-4)
    assert float(np.max(other.residuals)) == pytest.approx(float(np.max(plain.residuals)), abs=1e-4)


def _yaw(v):
    return np.degrees(np.arctan2(v[..., 1], v[..., 0]))


def _facing(heads, hips_l, hips_r, root, neck):
    """The body's forward (…,3) of world heads (…,J,3): left (right hip -> left hip) x up (root -> neck)."""
    left = heads[..., hips_l, :] - heads[..., hips_r, :]
    up = heads[..., neck, :] - heads[..., root, :]
    return np.cross(left, up)


def _angle(a, b):
    return np.abs((a - b + 180.0) % 360.0 - 180.0)


@pytest.mark.parametrize("turn", [90.0, 180.0, -90.0])
def test_a_character_facing_another_way_keeps_its_facing_and_walks_forward(turn):
    """The metarig turned in its data (object axes untouched) to face +X, +Y or -X: retargeting the walk
    (its source faces -Y) leaves it facing where it faces at rest (within 10 degrees on every frame), and it
    walks the way it faces as the source walks the way the source faces (within 10 degrees). Before, it was
    turned to face the source's world direction."""
    source = import_walk()
    target = add_metarig(1.0, location=(0.0, 0.0, 0.0))
    select_only(target)
    target.rotation_euler[2] = np.radians(turn)
    bpy.ops.object.transform_apply(location=False, rotation=True, scale=False)
    bpy.context.view_layer.update()
    outcome = retarget.retarget(bpy.context, source, target, *FRAMES)
    frames = outcome.frames
    names = [b.name for b in target.data.bones]
    t_bones = [names.index(n) for n in ("thigh.L", "thigh.R", "spine", "spine.004")]
    s_names = [b.name for b in source.data.bones]
    s_bones = [s_names.index(n) for n in ("LeftUpLeg", "RightUpLeg", "Hips", "Neck")]
    rest = np.array([np.array(target.matrix_world @ target.data.bones[n].head_local) for n in names])
    rest_yaw = _yaw(_facing(rest, *t_bones))
    t_heads, s_heads = world_heads(target, frames), world_heads(source, frames)
    t_yaw, s_yaw = _yaw(_facing(t_heads, *t_bones)), _yaw(_facing(s_heads, *s_bones))
    assert _angle(t_yaw, rest_yaw).max() < 10.0
    t_travel = t_heads[-1, t_bones[2]] - t_heads[0, t_bones[2]]
    s_travel = s_heads[-1, s_bones[2]] - s_heads[0, s_bones[2]]
    assert np.linalg.norm(t_travel[:2]) > 0.5
    relative_t = _yaw(t_travel) - np.median(t_yaw)
    relative_s = _yaw(s_travel) - np.median(s_yaw)
    assert _angle(relative_t, relative_s) < 10.0


@pytest.mark.parametrize("system, scale, units", [('METRIC', 1.0, "m"), ('METRIC', 0.01, "scene units"),
                                                 ('NONE', 1.0, "scene units")])
def test_the_report_says_what_its_distances_are_in(system, scale, units):
    source = import_walk()
    target = add_metarig(1.0)
    bpy.context.scene.unit_settings.system = system
    bpy.context.scene.unit_settings.scale_length = scale
    outcome = retarget.retarget(bpy.context, source, target, *FRAMES)
    assert outcome.units == outcome.contact_report["units"] == units
    assert f"largest residual {float(np.max(outcome.residuals)):.3g} {units};" in outcome.summary()
