# SPDX-License-Identifier: GPL-3.0-or-later
"""Mirror Pose: an armature's current pose mirrored across its own sagittal plane, left and right swapped through
its bone map (solver/retarget/mirror.py does the math). The pose bones' channels are set, nothing is keyed: the
user keys the mirrored pose as any other. ``retarget --mirror`` mirrors the source's motion in run.prepare."""

import numpy as np

from ...solver import SolverInputError
from ...solver.retarget import motion as rt
from ...solver.retarget.mirror import mirror_basis
from ..errors import AdjustError
from ..reading import pose, start_checks
from ..rig import control_rig, mapping
from .read import pose_property, rig_of


def mirror_armature_pose(obj):
    """Mirror ``obj``'s pose in place: every pose bone's channels (location, rotation in its mode, scale) set to
    its partner's, reflected (solver.retarget.mirror.mirror_basis: the bones' own channels, not constraints). Returns the number of bones posed; AdjustError (one line) before anything changes."""
    start_checks.check_armature(obj)
    if obj.mode == 'EDIT':
        raise AdjustError(f"'{obj.name}' is in Edit Mode: leave it to mirror its pose")
    if control_rig.is_generated_rigify(obj):
        raise AdjustError(f"'{obj.name}' is a generated control rig: mirror its pose with Blender's own "
                          f"Paste Pose Flipped")
    rig = rig_of(obj, mapping.read_map(obj))
    basis = pose_property(obj.pose.bones, "matrix_basis", (4, 4)).transpose(0, 2, 1)
    try:
        new_basis = mirror_basis(rig, basis[None])  # (1,J,4,4)
    except SolverInputError as ex:
        raise AdjustError(f"Cannot mirror '{obj.name}': {ex}") from None
    _set_channels(obj, new_basis)
    return new_basis.shape[1]


def _set_channels(obj, basis):
    """Each pose bone's location, rotation (in its mode, nearest its current value) and scale from its
    matrix_basis (1,J,4,4), converted in float64 (Blender's matrix_basis setter converts in float32)."""
    pose_bones = obj.pose.bones
    modes = pose.rotation_modes(obj)
    rotation = rt.unit_columns(basis[..., :3, :3])
    values = {"location": basis[0, :, :3, 3], "scale": np.linalg.norm(basis[0, :, :3, :3], axis=1)}
    for mode in sorted(set(modes)):
        bones = [j for j, m in enumerate(modes) if m == mode]
        prop = rt.ROTATION_PROPERTY[mode]
        current = pose_property(pose_bones, prop, (pose.CHANNEL_SIZES[prop],))[bones]
        values.setdefault(prop, {}).update(zip(bones, rt.rotation_channel(mode, rotation[:, bones], current)[0]))
    for j, pose_bone in enumerate(pose_bones):
        pose_bone.location = values["location"][j]
        pose_bone.scale = values["scale"][j]
        prop = rt.ROTATION_PROPERTY[modes[j]]
        setattr(pose_bone, prop, values[prop][j])
