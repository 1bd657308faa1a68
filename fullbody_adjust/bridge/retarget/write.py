"""Writing a retarget's result (see bridge/retarget/run.py): the solved pose keyed into a new action assigned to the
target, on its mapped bones or, on a generated control rig, on the controls that pose them."""

import bpy
import numpy as np

from ...solver.retarget import motion as rt
from .. import adjustment
from ..rig import control_rig, mapping
from ..writing import keyframes
from ..reading import pose
from ..rig.control_frames import control_channels
from .read import pose_property
from .partial import action_without


def write_pose(context, target_obj, target, pose_matrices, frames, action_name, carried=(), only=None):
    """Key every mapped bone of ``target_obj`` (``target`` its Rig) at ``pose_matrices`` (F,J,4,4, armature
    space) over ``frames`` into a new action named ``action_name``, assigned to it: each bone's rotation in
    its rotation mode, and the root's location; on a control rig, the controls that pose the mapped bones.
    ``carried``: bones outside the map keyed as well (fingers carried over). Returns (action, keyed bone
    names). ``only``: just these bones written, into a copy of the target's action (partial.action_without)."""
    written = sorted({b for bones in target.groups.values() for b in bones} | {int(b) for b in carried})
    if only is not None:
        written = [b for b in written if b in set(only)]
    if control_rig.is_generated_rigify(target_obj):
        action = _new_action(target_obj, action_name)  # before posing: the old action no longer drives the controls
        bone_map = mapping.BoneMap({g: [target.names[b] for b in bones] for g, bones in target.groups.items()})
        scale = float(np.linalg.norm(target.matrix_world[:3, 0]))
        tolerance = adjustment.settings_of(target_obj).chain.tolerance / scale
        channels = control_channels(target_obj, context.view_layer, control_rig.control_pairs(target_obj, bone_map),
                                    [target.names[b] for b in written], pose_matrices[:, written], tolerance,
                                    range(len(frames)))
        keyframes.key_bones_frames(target_obj, None, frames, channels)
        # A rig with drivers already has animation data: the depsgraph learns of the new action's curves only
        # when told (a rig without any animation before picks them up on the frame change).
        target_obj.update_tag(refresh={'TIME'})
        context.scene.frame_set(context.scene.frame_current)
        return action, tuple(channels)
    basis = rt.basis_from_pose(target, pose_matrices, written)
    modes = pose.rotation_modes(target_obj)
    channels = _channels(target_obj, target, basis, written, modes)
    action = _new_action(target_obj, action_name) if only is None else \
        action_without(target_obj, action_name, [target.names[b] for b in written])
    keyframes.key_bones_frames(target_obj, None, frames, channels)
    context.scene.frame_set(context.scene.frame_current)  # show the new action's pose
    return action, tuple(channels)


def _channels(obj, rig, basis, written, modes):
    """{bone: {property: (F,n)}}: each written bone's rotation in its mode, continuous from its current value;
    the root's location too."""
    rotation = rt.unit_columns(basis[..., :3, :3])  # scale removed
    out = {rig.names[j]: {} for j in written}
    for mode in sorted({modes[j] for j in written}):  # one conversion per rotation mode
        columns = [k for k, j in enumerate(written) if modes[j] == mode]
        prop = rt.ROTATION_PROPERTY[mode]
        current = pose_property(obj.pose.bones, prop, (pose.CHANNEL_SIZES[prop],))
        values = rt.rotation_channel(mode, rotation[:, columns], current[[written[k] for k in columns]])
        for c, k in enumerate(columns):
            out[rig.names[written[k]]][prop] = values[:, c]
    root = rig.groups["root"][0]
    if root in written:
        out[rig.names[root]]["location"] = basis[:, written.index(root), :3, 3]
    return out


def _new_action(obj, name):
    """A new, empty action named ``name`` (Blender adds .001 if the name is taken) assigned to ``obj``; its
    previous action is kept (keyframes.assign_action)."""
    action = bpy.data.actions.new(name)
    keyframes.assign_action(obj, action)
    return action
