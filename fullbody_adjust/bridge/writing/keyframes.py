"""Keyframes for pose bones, written straight into F-Curves, on every supported Blender:
4.2 (legacy actions: ``action.fcurves``, groups named after the bones), 4.4/4.5 (slotted actions: the
object must have an action slot assigned, or the action animates nothing) and 5.x (layered actions,
F-Curves in the slot's channelbag).

Keys are merged: a key at a frame that already has one (within Blender's own 0.01-frame threshold)
replaces that key's value, keys on other frames and F-Curves of other bones or properties are never
touched. New keys take the interpolation of the key before them on the same F-Curve (after them when
there is none before; the user's default for a new F-Curve), as Blender's own keying does, and the
user's default handle type.

Frames are scene frames; in NLA tweak mode they are mapped into the tweaked action's time. The pose in
the scene is left as it is: keys show on the next frame change.
"""

import bpy
import numpy as np

from ..errors import AdjustError
from ..reading.pose import CHANNEL_SIZES

# Blender's BEZT_BINARYSEARCH_THRESH: keys closer than this are at the same frame.
SAME_FRAME = 0.01

_KEYFRAME_PROPS = bpy.types.Keyframe.bl_rna.properties
_INTERPOLATION = {item.identifier: item.value for item in _KEYFRAME_PROPS["interpolation"].enum_items}
_HANDLE_TYPE = {item.identifier: item.value for item in _KEYFRAME_PROPS["handle_left_type"].enum_items}
# What keyframe_points.add gives every new key (Blender ignores the preferences there): a fresh F-Curve
# needs these written only when they differ, and auto handles are recalculated by fcurve.update() whatever
# they were.
_ADDED_INTERPOLATION = _INTERPOLATION["BEZIER"]
_ADDED_HANDLE_TYPE = _HANDLE_TYPE["AUTO_CLAMPED"]
_AUTO_HANDLES = (_HANDLE_TYPE["AUTO"], _HANDLE_TYPE["AUTO_CLAMPED"])

# 4.4 introduced slotted actions; 5.0 gave fcurve_ensure_for_datablock its group_name.
_LAYERED = "layers" in bpy.types.Action.bl_rna.properties
_ENSURE_TAKES_GROUP = bpy.app.version >= (5, 0, 0)


def key_bones_frames(obj, bone_names, frames, values_by_channel, *, action_name=None):
    """Key many frames at once: ``values_by_channel`` maps each bone name to {property: (F,k) array}
    (as armature_rotations_to_channels returns for a batched snapshot), properties among location,
    rotation_quaternion, rotation_euler, rotation_axis_angle, scale; ``frames`` (F,) scene frames.
    ``bone_names`` (None: every bone in values_by_channel) selects which bones to key. One foreach_set
    per F-Curve and array; keys on other frames are kept, keys on these frames replaced. Everything is
    checked before anything is written. Returns the action written to."""
    frames = np.asarray(frames, dtype=np.float64).reshape(-1)
    if len(frames) == 0 or not np.all(np.isfinite(frames)):
        raise ValueError("key_bones_frames needs at least one finite frame")
    if len(frames) > 1 and np.min(np.diff(np.sort(frames))) < SAME_FRAME:
        raise ValueError("key_bones_frames: two frames are the same")
    names = list(values_by_channel) if bone_names is None else list(bone_names)
    plan = []
    for name in names:
        _pose_bone(obj, name)
        if name not in values_by_channel:
            raise ValueError(f"key_bones_frames: no values for bone '{name}'")
        for prop, values in values_by_channel[name].items():
            size = CHANNEL_SIZES.get(prop)
            if size is None:
                raise ValueError(f"key_bones_frames: bone '{name}': cannot key '{prop}'")
            values = np.asarray(values, dtype=np.float64)
            if values.shape == (size,) and len(frames) == 1:
                values = values[None]
            if values.shape != (len(frames), size):
                raise ValueError(f"key_bones_frames: bone '{name}' {prop} must have shape "
                                 f"{(len(frames), size)}, got {values.shape}")
            if not np.all(np.isfinite(values)):
                raise ValueError(f"key_bones_frames: bone '{name}' {prop} has NaN/inf")
            plan.append((name, prop, values))

    action = ensure_action(obj, action_name)
    action_frames = _action_time(obj.animation_data, frames)
    curves = _FCurves(obj, action)
    for name, prop, values in plan:
        path = f'pose.bones["{bpy.utils.escape_identifier(name)}"].{prop}'
        for index in range(values.shape[1]):
            merge_keys(curves.ensure(path, index, group=name), action_frames, values[:, index])
    return action


def key_object_frames(obj, action, frames, values_by_property):
    """Key the object's own channels (``values_by_property``: {location / rotation_*: (F,n)}) at scene
    ``frames`` (F,) into ``action`` (assigned to it), merged as key_bones_frames merges bone keys."""
    action_frames = _action_time(obj.animation_data, np.asarray(frames, dtype=np.float64).reshape(-1))
    curves = _FCurves(obj, action)
    for prop, values in values_by_property.items():
        values = np.asarray(values, dtype=np.float64)
        for index in range(values.shape[1]):
            merge_keys(curves.ensure(prop, index, group="Object Transforms"), action_frames, values[:, index])


def ensure_action(obj, new_action_name=None):
    """The action keys go into, assigned to ``obj``: its current one, or a new one named
    '<object>Action' when it has none. With ``new_action_name``: a copy of the current action (or an
    empty one) under that name is assigned instead, so the original action stays intact; the original
    is kept (see assign_action). When the assigned action already has that name it is
    used as it is, so keying frame by frame with the same name makes one new action."""
    anim = obj.animation_data or obj.animation_data_create()
    original = anim.action
    if new_action_name is None:
        if original is not None:
            return original
        anim.action = bpy.data.actions.new(f"{obj.name}Action")
        return anim.action
    if original is not None and original.name == new_action_name:
        return original  # already writing into it (e.g. keyed frame by frame)
    if anim.use_tweak_mode:
        raise AdjustError(f"'{obj.name}' is in NLA tweak mode: leave it to write into a new action")
    action = original.copy() if original is not None else bpy.data.actions.new(new_action_name)
    action.name = new_action_name
    slot_identifier = anim.action_slot.identifier if _LAYERED and anim.action_slot else None
    assign_action(obj, action)
    if slot_identifier and anim.action_slot is None and slot_identifier in action.slots:
        # The copy has the same slots; keep animating through the one the object used.
        anim.action_slot = action.slots[slot_identifier]
    return action


def assign_action(obj, action):
    """Assign ``action`` to ``obj`` in place of its current one, which is kept: it gets a fake user when nothing
    else uses it, so saving the file does not drop it."""
    anim = obj.animation_data or obj.animation_data_create()
    previous = anim.action
    if previous is not None and previous != action and previous.users <= 1:
        previous.use_fake_user = True
    anim.action = action


def animating_fcurves(obj):
    """The F-Curves that animate ``obj`` through its action: the action's own (4.2), or those of the slot the
    object animates through (4.4+; none without a slot)."""
    anim = obj.animation_data
    if anim is None or anim.action is None:
        return []
    return list(_FCurves(obj, anim.action).by_path.values())


def merge_keys(fcurve, frames, values):
    """Write keys (frames (F,), values (F,)) into ``fcurve``: replace the value of a key already at a frame
    (its handles move with it), add the others, keep every other key as it was; then sort and
    recalculate handles (fcurve.update())."""
    points = fcurve.keyframe_points
    count = len(points)
    frames = np.asarray(frames, dtype=np.float64)
    values = np.asarray(values, dtype=np.float64)
    if len(frames) == 1 and count and _replace_one_key(fcurve, points, count, float(frames[0]), float(values[0])):
        return
    if count == 0 and len(frames) and _added_keys_are_new_keys():
        # A fresh F-Curve whose new keys are what keyframe_points.add makes anyway: only their points to set.
        points.add(len(frames))
        points.foreach_set("co", np.stack([frames, values], axis=1).astype(np.float32).reshape(-1))
        fcurve.update()
        return
    co = _get(points, "co", count, 2, np.float32)
    left = _get(points, "handle_left", count, 2, np.float32)
    right = _get(points, "handle_right", count, 2, np.float32)

    match = _matching_keys(co[:, 0], frames)
    replaced = match >= 0
    if np.any(replaced):
        at = match[replaced]
        delta = values[replaced] - co[at, 1]
        co[at, 1] = values[replaced]
        left[at, 1] += delta
        right[at, 1] += delta

    added = ~replaced
    new_count = int(np.count_nonzero(added))
    if new_count:
        new_frames, new_values = frames[added], values[added]
        interpolation = _get(points, "interpolation", count, 1, np.int32)[:, 0]
        left_type = _get(points, "handle_left_type", count, 1, np.int32)[:, 0]
        right_type = _get(points, "handle_right_type", count, 1, np.int32)[:, 0]
        edit = bpy.context.preferences.edit
        handle_type = _HANDLE_TYPE[edit.keyframe_new_handle_type]
        co = np.concatenate([co, np.stack([new_frames, new_values], axis=1)]).astype(np.float32)
        # Flat handles one frame either side, as Blender's own keying starts them (auto types recalculate).
        left = np.concatenate([left, np.stack([new_frames - 1.0, new_values], axis=1)]).astype(np.float32)
        right = np.concatenate([right, np.stack([new_frames + 1.0, new_values], axis=1)]).astype(np.float32)
        interpolation = np.concatenate([interpolation, _new_interpolation(
            co[:count, 0], interpolation, new_frames, _INTERPOLATION[edit.keyframe_new_interpolation_type])])
        left_type = np.concatenate([left_type, np.full(new_count, handle_type, np.int32)])
        right_type = np.concatenate([right_type, np.full(new_count, handle_type, np.int32)])
        points.add(new_count)
        fresh = count == 0  # every key just added, with keyframe_points.add's defaults
        if not (fresh and np.all(interpolation == _ADDED_INTERPOLATION)):
            points.foreach_set("interpolation", interpolation.astype(np.int32))
        if not (fresh and handle_type == _ADDED_HANDLE_TYPE):
            points.foreach_set("handle_left_type", left_type)
            points.foreach_set("handle_right_type", right_type)
        recalculated = fresh and handle_type in _AUTO_HANDLES
    else:
        recalculated = False
    if new_count or np.any(replaced):
        points.foreach_set("co", co.reshape(-1))
        if not recalculated:
            points.foreach_set("handle_left", left.reshape(-1))
            points.foreach_set("handle_right", right.reshape(-1))
        fcurve.update()


# Up to this many keys on a curve, _replace_one_key finds the key in plain floats (a click's curves); numpy beyond.
_FEW_KEYS = 16


def _replace_one_key(fcurve, points, count, frame, value):
    """merge_keys for one frame that already has a key, on an F-Curve in frame order (as fcurve.update()
    leaves it): that key alone is rewritten, the same way (its handles move with it). Clicks key one frame,
    and rewriting every key of every curve costs more than the solve's keys are worth. False (nothing
    written) when the general path is needed."""
    co = _get(points, "co", count, 2, np.float32)
    if count <= _FEW_KEYS:  # numpy's per-call cost was most of a click's keying
        existing = co[:, 0].tolist()
        if not all(a < b for a, b in zip(existing, existing[1:])):
            return False
        at = min(range(count), key=lambda i: abs(existing[i] - frame))
        distance = abs(existing[at] - frame)
    else:
        existing = co[:, 0].astype(np.float64)
        if not np.all(existing[1:] > existing[:-1]):
            return False
        at = int(np.argmin(np.abs(existing - frame)))
        distance = abs(existing[at] - frame)
    if not distance < SAME_FRAME:
        return False
    # co_ui moves the key's handles by the same offset as the key, as moving it in the Graph Editor does: one
    # write where setting the value and both handles took three reads and writes (~4 us of ~12 per curve).
    points[at].co_ui = (float(co[at, 0]), value)
    fcurve.update()
    return True


# --- helpers --------------------------------------------------------------------------------------------


class _FCurves:
    """Finds or creates the F-Curves of one object's action, legacy or layered, grouped by bone name."""

    def __init__(self, obj, action):
        self.obj = obj
        self.action = action
        self.by_path = {(fc.data_path, fc.array_index): fc for fc in self._existing()}

    def _channelbag(self):
        slot = self.obj.animation_data.action_slot
        if slot is None:
            return None
        from bpy_extras import anim_utils
        return anim_utils.action_get_channelbag_for_slot(self.action, slot)

    def _existing(self):
        if not _LAYERED:
            return self.action.fcurves
        channelbag = self._channelbag()
        return channelbag.fcurves if channelbag is not None else ()

    def ensure(self, data_path, index, group):
        fcurve = self.by_path.get((data_path, index))
        if fcurve is not None:
            return fcurve
        if not _LAYERED:
            fcurve = self.action.fcurves.new(data_path, index=index, action_group=group)
        elif _ENSURE_TAKES_GROUP:
            fcurve = self.action.fcurve_ensure_for_datablock(self.obj, data_path, index=index, group_name=group)
        else:
            # Also creates the layer, strip and slot, and assigns the slot.
            fcurve = self.action.fcurve_ensure_for_datablock(self.obj, data_path, index=index)
            if fcurve.group is None:
                groups = self._channelbag().groups
                fcurve.group = groups.get(group) or groups.new(group)
        self.by_path[(data_path, index)] = fcurve
        return fcurve


def _added_keys_are_new_keys():
    """keyframe_points.add's keys (Bézier, auto clamped handles, recalculated by fcurve.update()) are what
    the user's preferences make new keys."""
    edit = bpy.context.preferences.edit
    return (_INTERPOLATION[edit.keyframe_new_interpolation_type] == _ADDED_INTERPOLATION
            and _HANDLE_TYPE[edit.keyframe_new_handle_type] == _ADDED_HANDLE_TYPE)


def _pose_bone(obj, name):
    pose_bone = obj.pose.bones.get(name) if obj is not None and obj.type == 'ARMATURE' else None
    if pose_bone is None:
        raise AdjustError(f"'{getattr(obj, 'name', obj)}' has no pose bone named '{name}'")
    return pose_bone


def _action_time(anim, frames):
    if not anim.use_tweak_mode:
        return frames
    return np.array([anim.nla_tweak_strip_time_to_scene(float(f), invert=True) for f in frames])


def _matching_keys(existing, frames):
    """For each of ``frames`` the index of the existing key at that frame (within SAME_FRAME), or -1."""
    match = np.full(len(frames), -1, dtype=int)
    if len(existing) == 0:
        return match
    order = np.argsort(existing, kind="stable")
    ordered = existing[order].astype(np.float64)
    right = np.clip(np.searchsorted(ordered, frames), 0, len(ordered) - 1)
    left = np.clip(right - 1, 0, len(ordered) - 1)
    nearest = np.where(np.abs(ordered[left] - frames) <= np.abs(ordered[right] - frames), left, right)
    close = np.abs(ordered[nearest] - frames) < SAME_FRAME
    match[close] = order[nearest[close]]
    return match


def _new_interpolation(existing_frames, existing_interpolation, new_frames, default):
    """Interpolation of each new key: that of the existing key before it, else after it, else default."""
    if len(existing_frames) == 0:
        return np.full(len(new_frames), default, np.int32)
    order = np.argsort(existing_frames, kind="stable")
    before = np.searchsorted(existing_frames[order], new_frames) - 1
    return existing_interpolation[order][np.clip(before, 0, None)].astype(np.int32)


def _get(collection, prop, count, size, dtype):
    buffer = np.empty(count * size, dtype=dtype)
    if count:
        collection.foreach_get(prop, buffer)
    return buffer.reshape(count, size)
