"""Live Adjust: while ``obj.fullbody_adjust.live`` is on, moving one of the armature's targets, poles or
obstacles (or the armature itself), changing a setting the solve reads and changing the frame re-solve the
current frame and show the pose, without keys. ``key_pose`` keys what is shown; turning Live off puts the keyed
pose back.

Every live solve starts from the *base* pose of the current frame: the animation evaluated there, with the
bones that are not animated as they were when Live was turned on or last keyed. So the pose shown is a
function of the targets alone (a target moved back brings the body back), never of the previous live pose.
The base pose is read from Blender once per frame and kept as a PoseSnapshot; the channels Live changed
are put back to it before the frame changes and when Live is turned off.

Handlers (registered with the extension, kept across file loads): with no armature live they return at
once. They never keep bpy objects between calls (Undo and file loads replace them): the state is keyed by
object name and the objects are looked up on each call. A live solve's error is stored for the panel,
never raised out of a handler. Applying the pose makes Blender evaluate the armature again; that update
is not a reason to solve (only a target's, pole's or obstacle's transform, the armature's object transform, a
changed setting or the frame are: bridge/live_updates.py tells). A setting changed (its property's update calls
``settings_changed``) marks the armature's Live solve pending and tags the armature, so the update that follows
solves once, however many settings a script changes in between.

The obstacles' boxes are read once and kept (reading them goes through every object of the scene) until an update
may have changed them: a mesh that does not move with the armature moved or changed (read at once, and when the
boxes differ that solves again, as a moved target does), or the scene's objects or collections changed (added,
removed, shown, hidden). A new frame, Undo and a changed setting read them again too.
"""

from dataclasses import dataclass

import bpy
import numpy as np
from bpy.app.handlers import persistent

from ..solver.vocabulary import ROTATION_PROPERTY
from . import adjustment, live_updates
from .reading import frames, obstacles, pose, start_checks
from .writing import keyframes
from .rig import rig_cache, targets
from .errors import AdjustError

# How a live solve differs from Adjust Pose: no keys, a deleted target's slot is left out, and no residuals
# of the evaluated pose (measuring them costs a scene evaluation more; Blender evaluates what it shows anyway).
LIVE_OPTIONS = adjustment.Options(insert_keys=False, skip_missing_targets=True, evaluated_residuals=False)


@dataclass
class LiveState:
    """What Live keeps for one armature between handler calls (plain data, no bpy references)."""

    base: dict  # property -> (B,k) channel values of every pose bone when Live was turned on / last keyed
    bone_names: tuple  # the bones ``base`` rows belong to
    start: object = None  # PoseSnapshot of the base pose at ``start_frame``
    rig: object = None  # the rig_cache.Rig ``start`` was read with
    start_frame: float = None
    stale: bool = True  # read the base pose again before the next solve
    written: tuple = ()  # bones whose channels the last solve changed
    error: str = ""  # why the last solve failed, one line ("" when it went well)
    warning: str = ""  # what the last solve left out (a deleted target), one line
    pending: bool = False  # a setting changed: solve on the next update
    obstacle_corners: object = None  # obstacles.obstacle_boxes of the current frame, kept (None: read them again)
    pointer: int = 0  # the armature's as_pointer(): its state follows it through a rename


_states = {}  # armature object name -> LiveState, only for armatures with Live on
_busy = False  # set while Live itself changes the scene: updates caused by that are not a reason to solve


def state_of(obj):
    """The LiveState of armature ``obj`` when Live is on for it, else None."""
    state = _states.get(obj.name)
    return state if state is not None and obj.fullbody_adjust.live else None


def status(obj):
    """One line for the panel: why the last live solve failed or what it left out, or '' when neither."""
    state = state_of(obj)
    return (state.error or state.warning) if state is not None else ""


def live_toggled(obj, context):
    """``obj.fullbody_adjust.live`` was set: start (capture the base pose and solve) or stop (restore it)."""
    if obj.fullbody_adjust.live:
        if obj.type == 'ARMATURE' and obj.name not in _states:
            _states[obj.name] = _new_state(obj)
            _solve(obj, _states[obj.name], context)
    else:
        state = _states.pop(obj.name, None)
        if state is not None and obj.type == 'ARMATURE':
            _guarded(_restore, obj, state, _current_frame(context.scene))


def settings_changed(obj):
    """A setting of ``obj.fullbody_adjust`` the solve reads was changed: while Live is on, solve again on the next
    update (tagged here, so there is one)."""
    state = _states.get(obj.name) if not _busy else None
    if state is not None and obj.fullbody_adjust.live:
        state.pending, state.obstacle_corners = True, None
        obj.update_tag()


def key_pose(context, obj):
    """Key what Live shows: the bones Live moved, on the current frame (keys on other frames and other bones
    untouched). Their channels become the base pose. Returns the names of the bones keyed."""
    start_checks.check_armature(obj)
    state = state_of(obj)
    if state is None:
        raise AdjustError(f"Live Adjust is off for '{obj.name}': turn it on first")
    if state.error:
        raise AdjustError(f"Nothing to key: {state.error}")
    names = state.written
    if not names:
        return ()
    bones = obj.pose.bones
    values = {}
    for name in names:
        pose_bone = bones[name]
        rotation = ROTATION_PROPERTY[pose_bone.rotation_mode]
        props = {rotation: np.array(getattr(pose_bone, rotation), dtype=np.float64)}
        i = state.start.index(name)
        for prop in ("location", "scale"):  # as Adjust Pose: an unmoved location (or scale) is not keyed
            value = np.array(getattr(pose_bone, prop), dtype=np.float64)
            if not np.array_equal(value, state.start.channels[prop][i]):
                props[prop] = value
        values[name] = props
    keyframes.key_bones_frames(obj, names, [context.scene.frame_current], values)
    _capture_base(obj, state, names)
    state.written = ()
    state.stale = True  # the keyed pose is the base now: read it again before the next solve
    return names


# --- handlers -------------------------------------------------------------------------------------------


@persistent
def _on_depsgraph_update(scene, depsgraph):
    if not _states or _busy:
        return
    live, gone = [], False
    for name in list(_states):
        obj = _live_object(name)
        if obj is None:
            gone = True
            continue
        state = _states[obj.name]
        # On every update: one that moved nothing may have changed them.
        live_updates.follow_obstacles(obj, state, depsgraph)
        live.append((obj, state))
    moved = {update.id.name for update in depsgraph.updates
             if update.is_updated_transform and isinstance(update.id, bpy.types.Object)}
    for obj, state in live:
        if obj.name in moved and live_updates.object_moved(obj, state):
            state.stale = True  # the base pose's world matrices moved with the object
            _solve(obj, state, bpy.context)
        elif state.pending or live_updates.inputs_moved(obj, moved - {obj.name}):
            _solve(obj, state, bpy.context)
    if gone:
        _resync()  # Live switched off some other way (or the armature deleted): follow what the file says


@persistent
def _on_frame_change_pre(scene, depsgraph=None):
    if not _states or frames.stepping():  # the bridge reading frames: Live solves when it is back
        return
    # Put back what Live changed, so the new frame evaluates to its base pose (animation over base).
    for name in list(_states):
        obj = _live_object(name)
        if obj is not None:
            state = _states[obj.name]
            _guarded(_restore, obj, state, None)
            state.written, state.stale = (), True


@persistent
def _on_frame_change_post(scene, depsgraph=None):
    if not _states or frames.stepping():
        return
    for name in list(_states):
        obj = _live_object(name)
        if obj is not None and scene in obj.users_scene:
            _solve(obj, _states[obj.name], bpy.context)


@persistent
def _on_load_post(*_args):
    """A file was loaded: the live armatures are those of the new file."""
    _states.clear()
    _resync()


@persistent
def _on_undo_redo(*_args):
    """Undo and redo replace every object and may switch Live on or off: follow what the file now says."""
    for name in list(_states):
        obj = bpy.data.objects.get(name)
        if obj is None or not obj.fullbody_adjust.live:
            del _states[name]
        else:
            _states[name].stale = True
    _resync()


_HANDLERS = (
    ("depsgraph_update_post", _on_depsgraph_update),
    ("frame_change_pre", _on_frame_change_pre),
    ("frame_change_post", _on_frame_change_post),
    ("load_post", _on_load_post),
    ("undo_post", _on_undo_redo),
    ("redo_post", _on_undo_redo),
)


def register():
    for event, handler in _HANDLERS:
        getattr(bpy.app.handlers, event).append(handler)
    if isinstance(bpy.data, bpy.types.BlendData):  # at start-up the file is not there yet: load_post follows
        _resync()


def unregister():
    for event, handler in _HANDLERS:
        handlers = getattr(bpy.app.handlers, event)
        if handler in handlers:
            handlers.remove(handler)
    _states.clear()


# --- the solve ------------------------------------------------------------------------------------------


def _solve(obj, state, context):
    """Solve the current frame from its base pose and show the result; errors are stored, never raised."""
    global _busy
    _busy = True
    try:
        frame = _current_frame(context.scene)
        rig = rig_cache.rig_of(obj)  # another Rig when the armature was edited: its base pose is read again
        if state.stale or state.start_frame != frame or state.rig is not rig:
            _restore(obj, state, frame)
            state.start, state.start_frame, state.written = pose.read_pose(obj, rig.static(obj)), frame, ()
            state.rig, state.stale, state.obstacle_corners = rig, False, None
        if state.obstacle_corners is None:
            state.obstacle_corners = obstacles.obstacle_boxes(obj, context)
        state.pending = False
        outcome = adjustment.adjust_pose(context, obj, LIVE_OPTIONS, start=state.start, rig=rig,
                                         obstacle_corners=state.obstacle_corners)
    except AdjustError as ex:
        state.error, state.warning = str(ex), ""
        _restore(obj, state, frame)
        state.written = ()
    except Exception as ex:  # a handler must not raise: Blender would print it on every update
        state.error, state.warning = f"Live Adjust failed: {type(ex).__name__}: {ex}", ""
        state.written = ()
    else:
        state.error, state.warning = "", _missing_targets(obj, context.scene)
        # Bones the previous solve moved and this one leaves alone go back to the base pose.
        _restore(obj, state, frame, keep=set(outcome.moved_bones))
        state.written = outcome.moved_bones
    finally:
        _busy = False


def _restore(obj, state, frame, keep=()):
    """Put the channels of the bones Live wrote (but those in ``keep``) back to the base pose: that of the
    base snapshot when it is of ``frame``, else those captured when Live started or last keyed (the
    animation then overwrites what it animates)."""
    if state.start is not None and state.start_frame == frame:
        names, channels = state.start.names, state.start.channels
    else:
        names, channels = state.bone_names, state.base
    index = {name: i for i, name in enumerate(names)}
    bones = obj.pose.bones
    for name in state.written:
        pose_bone = bones.get(name)
        if name in keep or pose_bone is None or name not in index:
            continue
        i = index[name]
        for prop in ("location", ROTATION_PROPERTY[pose_bone.rotation_mode], "scale"):
            value = channels[prop][i]
            if not np.array_equal(np.array(getattr(pose_bone, prop), dtype=np.float32), value.astype(np.float32)):
                setattr(pose_bone, prop, tuple(float(v) for v in value))


def _guarded(function, *args):
    global _busy
    _busy = True
    try:
        function(*args)
    finally:
        _busy = False


# --- state ----------------------------------------------------------------------------------------------


def _new_state(obj):
    state = LiveState(base={}, bone_names=(), pointer=obj.as_pointer())
    _capture_base(obj, state)
    return state


def _capture_base(obj, state, names=None):
    """Take the pose bones' current channels as the base (all bones, or only ``names``)."""
    bones = obj.pose.bones
    current = {prop: _channel_values(bones, prop, size) for prop, size in pose.CHANNEL_SIZES.items()}
    bone_names = tuple(bones.keys())
    if names is None or bone_names != state.bone_names:
        state.base, state.bone_names = current, bone_names
        return
    rows = [bone_names.index(name) for name in names]
    for prop, values in current.items():
        state.base[prop][rows] = values[rows]


def _channel_values(bones, prop, size):
    values = np.empty(len(bones) * size, dtype=np.float32)
    bones.foreach_get(prop, values)
    return values.reshape(-1, size).astype(np.float64)


def _resync():
    """Start Live for every armature whose ``live`` is on but has no state yet (a file just loaded, Undo)."""
    context = bpy.context
    for obj in bpy.data.objects:
        if obj.type == 'ARMATURE' and obj.fullbody_adjust.live:
            state = _states.get(obj.name)
            if state is None:
                state = _states[obj.name] = _new_state(obj)
            if getattr(context, "scene", None) is not None and context.scene in obj.users_scene:
                _solve(obj, state, context)


def _live_object(name):
    """The armature whose Live state is kept under ``name`` (under its new name, when it was renamed) while Live
    is on for it; forgets its state otherwise."""
    obj = bpy.data.objects.get(name)
    if obj is None and name in _states:  # renamed: the state (its base pose) follows the object
        pointer = _states[name].pointer
        obj = next((o for o in bpy.data.objects if o.as_pointer() == pointer), None)
        if obj is not None and obj.name not in _states:
            _states[obj.name] = _states.pop(name)
            name = obj.name
    if obj is None or obj.type != 'ARMATURE' or not obj.fullbody_adjust.live:
        _states.pop(name, None)
        return None
    return obj


def _missing_targets(obj, scene):
    for slot in obj.fullbody_adjust.targets:
        if slot.enabled:
            missing = targets.missing_target(slot, scene)
            if missing is not None:
                return f"{missing}: left out"
    return ""


def _current_frame(scene):
    return scene.frame_current + scene.frame_subframe
