"""Target slots on the armature object and the empties they point at.

Each armature carries ``obj.fullbody_adjust.targets``: one slot per effector with
``effector``, ``target`` (an Object, normally an empty), ``priority`` (higher wins) and ``enabled``.
This module keeps those slots in shape, creates the target empties, and reads the targets' world
transforms (evaluated, so animated or parented targets count) as plain numpy arrays for the solver.
"""

from dataclasses import dataclass
import math
from typing import NamedTuple

import bpy
import numpy as np

from ...solver.vocabulary import DEFAULT_PRIORITY, EFFECTORS
from ..errors import AdjustError
from ..reading.frames import step_frames


# The head target is optional: without it the head rides on the chest, so linking a
# head empty does not switch its slot on by itself.
ENABLED_WHEN_LINKED = frozenset(("hand.L", "hand.R", "foot.L", "foot.R"))

NO_ENABLED_TARGET = "No enabled target: set a target object in the Full Body panel"


@dataclass(frozen=True)
class TargetSpec:
    """One enabled target as the solver needs it (world space, scene units)."""

    effector: str
    name: str  # the target object's name, for reports
    position: np.ndarray  # (3,)
    rotation: np.ndarray  # (3, 3) world rotation without scale, for the optional orientation drive
    priority: int
    use_rotation: bool = False  # the effector takes ``rotation``
    pole: np.ndarray = None  # (3,) world position of the slot's pole (hands and feet), or None


class FrameTargets(NamedTuple):
    """The enabled targets on one frame, EFFECTORS order, NaN where an effector has none."""

    positions: np.ndarray  # (E,3)
    rotations: np.ndarray  # (E,3,3) world rotations without scale
    poles: np.ndarray  # (E,3) pole positions (NaN: no pole)
    oriented: np.ndarray  # (E,) bool: the slot's use_rotation


# Effectors that bend a hinge (elbow, knee) below them and so can use a pole.
POLED = frozenset(("hand.L", "hand.R", "foot.L", "foot.R"))


def ensure_slots(obj):
    """Give ``obj`` exactly one target slot per effector, in EFFECTORS order; returns the slots.

    Existing slots keep their settings; duplicates of an effector (only the first counts) are
    dropped. New slots start without a target and therefore disabled, with the default priority.
    """
    slots = obj.fullbody_adjust.targets
    seen = set()
    duplicates = []
    for index, slot in enumerate(slots):
        if slot.effector in seen:
            duplicates.append(index)
        seen.add(slot.effector)
    for index in reversed(duplicates):
        slots.remove(index)
    for effector in EFFECTORS:
        if effector not in seen:
            slot = slots.add()
            slot.effector = effector
            slot.target = None
            slot.priority = DEFAULT_PRIORITY[effector]
            slot.enabled = False
    # Order by EFFECTORS; re-read the effectors each step since move() shifts the items.
    for wanted, effector in enumerate(EFFECTORS):
        current = [slot.effector for slot in slots].index(effector)
        if current != wanted:
            slots.move(current, wanted)
    return slots


def target_name(obj, effector):
    return f"{obj.name}_{effector}"


def targets_collection_name(obj):
    return f"{obj.name}_targets"


def create_targets(context_or_scene, obj, effector_positions, size, *, reset=False):
    """Make (or reuse) one empty per effector and link it in the effector's slot.

    effector_positions: {effector: (3,) world position}, e.g. the current wrists, ankles and head.
    size: display size of new empties, in scene units (pass something relative to the rig).
    An empty is reused when the slot already points at an object in the scene, or when an empty
    named "<armature>_<effector>" exists; a reused empty stays where the user put it unless
    ``reset`` is true. Hands and feet are enabled; the head slot keeps its enabled state.
    Returns {effector: empty}. Raises AdjustError, changing nothing, on a non-finite position.
    """
    scene = context_or_scene if isinstance(context_or_scene, bpy.types.Scene) else context_or_scene.scene
    positions = {}
    for effector, position in effector_positions.items():
        if effector not in EFFECTORS:
            raise ValueError(f"unknown effector {effector!r} (expected one of {', '.join(EFFECTORS)})")
        position = np.asarray(position, dtype=np.float64)
        if position.shape != (3,):
            raise ValueError(f"position for {effector} must have shape (3,), got {position.shape}")
        if not np.all(np.isfinite(position)):
            raise AdjustError(f"The current position of {effector} on '{obj.name}' is not finite")
        positions[effector] = position
    if not (math.isfinite(size) and size > 0):
        raise ValueError(f"size must be a positive finite number, got {size!r}")

    collection = _targets_collection(scene, obj)
    slots = ensure_slots(obj)
    created = {}
    for effector, position in positions.items():
        slot = slots[EFFECTORS.index(effector)]
        empty, placed = _reusable_target(scene, obj, effector, slot.target)
        if empty is None:
            empty = bpy.data.objects.new(target_name(obj, effector), None)
        if not _in_scene(scene, empty):
            collection.objects.link(empty)
        if not placed or reset:
            _place(empty, position, size)
        slot.target = empty
        if effector in ENABLED_WHEN_LINKED:
            slot.enabled = True
        created[effector] = empty
    return created


def _targets_collection(scene, obj):
    name = targets_collection_name(obj)
    collection = bpy.data.collections.get(name)
    if collection is None:
        collection = bpy.data.collections.new(name)
    if collection not in scene.collection.children_recursive:
        scene.collection.children.link(collection)
    return collection


def _reusable_target(scene, obj, effector, current):
    """(object to reuse or None, whether the user may already have placed it)."""
    if current is not None and _in_scene(scene, current):
        return current, True
    named = bpy.data.objects.get(target_name(obj, effector))
    if named is None or named.type != 'EMPTY' or named.library is not None:
        return None, False
    # A named empty outside the scene was deleted from it: bring it back as if new.
    return named, _in_scene(scene, named)


def _place(empty, position, size):
    world = empty.matrix_world.copy()  # keeps a reused empty's rotation (and parenting)
    world.translation = position
    empty.matrix_world = world
    empty.empty_display_type = 'SPHERE'
    empty.empty_display_size = size
    empty.show_in_front = True


def _in_scene(scene, ob):
    # ob.users_scene looks through every scene's collections; a name lookup in the scene's objects is the
    # quick answer unless another object (from a library) has the same name.
    found = scene.objects.get(ob.name)
    return found == ob or (found is not None and scene in ob.users_scene)


def missing_target(slot, scene):
    """Why an enabled slot's target cannot be read (one line), or None when it can."""
    target = slot.target
    if target is None:
        return f"Target for {slot.effector} is missing (deleted?)"
    if not _in_scene(scene, target):
        return f"Target '{target.name}' for {slot.effector} is missing from the scene (deleted?)"
    return None


def _enabled_targets(obj, scene, skip_missing=False):
    """[(effector, slot, target object)] of the enabled slots; AdjustError if any is unusable (with
    ``skip_missing``, a slot whose target is gone is left out instead)."""
    enabled = []
    for slot in obj.fullbody_adjust.targets:
        if not slot.enabled:
            continue
        target = slot.target
        missing = missing_target(slot, scene)
        if missing is not None:
            if skip_missing:
                continue
            raise AdjustError(missing)
        enabled.append((slot.effector, slot, target))
    if not enabled:
        raise AdjustError(NO_ENABLED_TARGET)
    return enabled


def _world_matrix(effector, target, depsgraph, frame=None, what="Target"):
    world = np.array(target.evaluated_get(depsgraph).matrix_world, dtype=np.float64)
    if not np.isfinite(world[:3, 3]).all():
        where = "" if frame is None else f" at frame {frame:g}"
        raise AdjustError(f"{what} '{target.name}' for {effector} has a non-finite location{where}")
    return world


def _pole_of(slot, scene):
    """The slot's pole object when it has one that counts (hands and feet); AdjustError if it left the scene."""
    pole = slot.pole if slot.effector in POLED else None
    if pole is not None and not _in_scene(scene, pole):
        raise AdjustError(f"Pole '{pole.name}' for {slot.effector} is missing from the scene (deleted?)")
    return pole


def _pole_position(effector, pole, depsgraph, frame=None):
    return _world_matrix(effector, pole, depsgraph, frame, what="Pole")[:3, 3].copy()


def _rotation_part(world):
    """World rotation of a 4x4 matrix with its scale removed (orthonormal columns). Plain floats, the operations
    of geometry.norm on the columns: numpy's per-call cost on one 3x3 matrix was half of reading a target."""
    rows = world[:3, :3].tolist()
    lengths = [math.sqrt(rows[0][j] * rows[0][j] + rows[1][j] * rows[1][j] + rows[2][j] * rows[2][j])
               for j in range(3)]
    lengths = [length if length > 0.0 else 1.0 for length in lengths]
    return np.array([[row[j] / lengths[j] for j in range(3)] for row in rows])


def read_targets(obj, depsgraph=None, *, skip_missing=False):
    """The enabled targets of ``obj`` (slot order) as TargetSpecs, from the evaluated scene.

    Raises AdjustError (one line, nothing changed) when no slot is enabled, an enabled slot's target
    is gone (with ``skip_missing``: that slot is left out), or a target's world location is not finite.
    """
    if depsgraph is None:
        depsgraph = bpy.context.evaluated_depsgraph_get()
    specs = []
    for effector, slot, target in _enabled_targets(obj, depsgraph.scene, skip_missing):
        world = _world_matrix(effector, target, depsgraph)
        pole = _pole_of(slot, depsgraph.scene)
        specs.append(TargetSpec(effector=effector, name=target.name, position=world[:3, 3].copy(),
                                rotation=_rotation_part(world), priority=int(slot.priority),
                                use_rotation=bool(slot.use_rotation) and effector != "head",
                                pole=None if pole is None else _pole_position(effector, pole, depsgraph)))
    return specs


def frame_targets(specs):
    """FrameTargets of read_targets' specs."""
    out = FrameTargets(np.full((len(EFFECTORS), 3), np.nan), np.full((len(EFFECTORS), 3, 3), np.nan),
                       np.full((len(EFFECTORS), 3), np.nan), np.zeros(len(EFFECTORS), dtype=bool))
    for spec in specs:
        column = EFFECTORS.index(spec.effector)
        out.positions[column], out.rotations[column] = spec.position, spec.rotation
        out.oriented[column] = spec.use_rotation
        if spec.pole is not None:
            out.poles[column] = spec.pole
    return out


def read_target_frames(obj, frames, context=None, *, rotations=False):
    """World positions (F, len(EFFECTORS), 3) of the enabled targets at each frame; NaN for effectors
    without an enabled target. With ``rotations=True`` returns (positions, rotations (F, E, 3, 3)).

    Steps the scene through ``frames`` (subframes allowed) with frame_set and restores the current
    frame afterwards, also on error. Same AdjustErrors as read_targets (the frame is named).
    """
    context = bpy.context if context is None else context
    frames = [float(frame) for frame in frames]
    read = target_frame_reader(obj, context)
    positions = np.full((len(frames), len(EFFECTORS), 3), np.nan)
    rotation_frames = np.full((len(frames), len(EFFECTORS), 3, 3), np.nan)
    for row, frame in step_frames(context.scene, frames):
        positions[row], rotation_frames[row] = read(frame)[:2]
    return (positions, rotation_frames) if rotations else positions


def target_frame_reader(obj, context):
    """A function of the current scene frame giving the FrameTargets (positions, rotations, poles, oriented),
    NaN for effectors without an enabled target. The slots are checked once, here."""
    enabled = [(effector, slot, target, _pole_of(slot, context.scene))
               for effector, slot, target in _enabled_targets(obj, context.scene)]
    oriented = np.array([any(e == effector and slot.use_rotation for e, slot, _t, _p in enabled)
                         and effector != "head" for effector in EFFECTORS])

    def read(frame):
        depsgraph = context.evaluated_depsgraph_get()
        positions = np.full((len(EFFECTORS), 3), np.nan)
        rotations = np.full((len(EFFECTORS), 3, 3), np.nan)
        poles = np.full((len(EFFECTORS), 3), np.nan)
        for effector, _slot, target, pole in enabled:
            world = _world_matrix(effector, target, depsgraph, frame)
            column = EFFECTORS.index(effector)
            positions[column] = world[:3, 3]
            rotations[column] = _rotation_part(world)
            if pole is not None:
                poles[column] = _pole_position(effector, pole, depsgraph, frame)
        return FrameTargets(positions, rotations, poles, oriented.copy())

    return read
