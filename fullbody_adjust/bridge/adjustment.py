"""The one way through: active armature → bone mapping → targets and obstacles → the solver → bone channels
→ keyframes. Operators and the command line call only ``adjust_pose`` and ``adjust_frames`` here.

The solve runs in the armature's own space (its object transform undone) scaled to world units (_solve_space):
bone lengths are rigid there even under non-uniform object scale, targets map into it exactly, every distance
the solver reports is in world units, and each obstacle is its mesh's bounding box with the mesh's rotation (an
oriented box) carried into it.
"""

from collections.abc import Callable
from contextlib import contextmanager
from dataclasses import dataclass, replace
from functools import cached_property

import numpy as np

from ..solver import Boxes, ChainSettings, SolverInputError
from ..solver.adjust import AdjustSettings, adjust_frames as solve_frames
from ..solver.adjust_types import UNCONSTRAINED
from ..solver.body import CHAIN, END, ROOT
from ..solver.geometry import norm
from ..solver.joint_ends import end_points
from ..solver.obstacle_reach import body_reach, skeleton_reach
from ..solver.obstacles import penetrations
from . import (control_rig, frames as frames_module, ik_limits, keyframes, limb_thickness, mapping, obstacles, pose,
               rig_cache, targets)
from .control_match import control_channels
from .errors import AdjustError


# A bone counts as moved when its rotation changed by more than this (radians, about) or its head moved by
# more than this fraction of the rig's size: below it, a key would only record float noise.
_MOVED = 1e-9

# A pose scale (or a bone length relative to the rig's size) at or below this counts as zero.
_FLAT = 1e-6

# A target further than this many rig sizes away is an error (see _check_target_distances).
_FAR = 1e6


@dataclass(frozen=True)
class Options:
    """What a run may override of the settings stored on the armature (None: use the stored value)."""

    variant: str = None  # 'FABRIK' | 'WEIGHTED' | 'PRIORITY'
    margin: float = None
    tolerance: float = None
    max_iterations: int = None
    use_joint_limits: bool = None
    keep_hand_orientation: bool = None
    skip_missing_targets: bool = False  # leave out an enabled slot whose target is gone instead of failing
    new_action: str = None  # write keys into a new action of this name (the original stays intact)
    insert_keys: bool = True
    # Residuals of the pose as Blender evaluates the applied result (a scene evaluation more), or the solver's.
    evaluated_residuals: bool = True


def missed_target_line(effectors, missed, residuals, why):
    """One line for the first effector with a target missed within reach: ``missed`` (F,E) bool, its frames
    (when F > 1), its largest residual and ``why`` (F,E) of that frame."""
    k = int(np.nonzero(missed.any(axis=0))[0][0])
    rows = np.nonzero(missed[:, k])[0]
    worst = rows[int(np.argmax(residuals[rows, k]))]
    frames = f" on {len(rows)} frames" if missed.shape[0] > 1 else ""
    return f"{effectors[k]} missed its target within reach{frames} by {residuals[worst, k]:.4g} ({why[worst, k]})"


@dataclass
class Outcome:
    """What a run did, in world units: per frame and effector (EFFECTORS order) residuals (NaN: no target)."""

    frames: np.ndarray  # (F,)
    effectors: tuple
    residuals: np.ndarray  # (F,E) world distance effector -> target (adjust_pose: as Blender evaluates the result)
    status: np.ndarray  # (F,E)
    reasons: np.ndarray  # (F,E)
    moved_bones: tuple
    # () -> ((F,) joints inside an obstacle box after the solve, (F,) bone segments crossing one): counted when first
    # asked for (joints_inside, segments_crossing); Live never asks.
    count_penetrations: Callable
    action: object = None

    @cached_property
    def _penetration_counts(self):
        return self.count_penetrations()

    @property
    def joints_inside(self):
        return self._penetration_counts[0]

    @property
    def segments_crossing(self):
        return self._penetration_counts[1]

    @property
    def constrained(self):
        return np.isfinite(self.residuals)

    @property
    def met(self):
        return self.status == "reached"

    def warning(self):
        """One line naming what went wrong although the run finished (the command line exits 1 for the same):
        a target within reach that was missed (the first effector, with its largest residual and why), or bones
        that end inside an obstacle; None when neither happened."""
        missed = self.constrained & ~self.met & (self.status != "unreachable")
        if missed.any():
            return missed_target_line(self.effectors, missed, self.residuals, self.reasons)
        inside, crossing = int(np.sum(self.joints_inside)), int(np.sum(self.segments_crossing))
        if inside or crossing:
            return f"bones end inside obstacles: {inside} joints inside, {crossing} bones crossing"
        return None

    def summary(self):
        """One line for the operator's report."""
        tasks = int(self.constrained.sum())
        met = int((self.met & self.constrained).sum())
        largest = float(np.nanmax(self.residuals)) if tasks else 0.0
        frames = len(self.frames)
        where = f" over {frames} frames" if frames > 1 else ""
        line = (f"{met} of {tasks} targets met{where}, largest residual {largest:.4g}; "
                f"{len(self.moved_bones)} bones keyed")
        inside, crossing = int(np.sum(self.joints_inside)), int(np.sum(self.segments_crossing))
        if inside or crossing:
            line += f"; obstacles: {inside} joints inside, {crossing} bones crossing"
        unmet = [(f, e) for f, e in zip(*np.nonzero(self.constrained & ~self.met))]
        if unmet:
            f, e = unmet[0]
            line += f"; {self.effectors[e]}: {self.reasons[f, e]}"
        return line


def check_armature(obj):
    """AdjustError (one line) unless ``obj`` is an armature whose pose and keys may be changed."""
    if obj is None:
        raise AdjustError("No active object: select an armature")
    if obj.type != 'ARMATURE':
        raise AdjustError(f"'{obj.name}' is not an armature")
    if obj.library is not None:
        raise AdjustError(f"Armature '{obj.name}' is linked from library '{obj.library.name}' and cannot be edited")
    if not obj.is_editable:
        raise AdjustError(f"Armature '{obj.name}' is not editable (a library override the file does not own)")
    action = obj.animation_data.action if obj.animation_data is not None else None
    if action is not None and not action.is_editable:
        where = f"linked from library '{action.library.name}'" if action.library is not None else "not editable"
        raise AdjustError(f"Action '{action.name}' of '{obj.name}' is {where} and cannot be keyed")
    if obj.matrix_world.to_3x3().determinant() <= 0.0:
        raise AdjustError(f"Armature '{obj.name}' has a negative or zero scale: fix its scale first")


def settings_of(obj, options=Options()):
    """The solver settings from the armature's stored settings, with ``options`` overriding."""
    stored = obj.fullbody_adjust

    def pick(name):
        value = getattr(options, name)
        return getattr(stored, name) if value is None else value

    chain = ChainSettings(tolerance=float(pick("tolerance")), max_iterations=int(pick("max_iterations")),
                          margin=float(pick("margin")))
    return AdjustSettings(chain=chain, variant=str(pick("variant")).lower(), use_limits=bool(pick("use_joint_limits")))


def adjust_pose(context, obj, options=Options(), start=None, rig=None, obstacle_corners=None):
    """Adjust the armature's pose at the current frame, apply it, and key the bones that moved. ``start``:
    the pose to solve from, a PoseSnapshot of this frame (default: the pose as it is now); ``rig``: its
    rig_cache.Rig, when the caller just looked it up; ``obstacle_corners``: obstacles.obstacle_boxes of this
    frame, when the caller keeps them (default: read now)."""
    frame = context.scene.frame_current
    return _run(context, obj, [frame], options, apply_pose=True, start=start, rig=rig, corners=obstacle_corners)


def adjust_frames(context, obj, frame_start, frame_end, options=Options(), progress=None):
    """Adjust every frame of [frame_start, frame_end] in one vectorised solve and key the moved bones."""
    if frame_end < frame_start:
        raise AdjustError(f"Frame range {frame_start}..{frame_end} is empty")
    frames = np.arange(frame_start, frame_end + 1, dtype=np.float64)
    return _run(context, obj, frames, options, apply_pose=False, progress=progress)


def _run(context, obj, frames, options, *, apply_pose, progress=None, start=None, rig=None, corners=None):
    progress = progress or (lambda stage, fraction: None)
    check_armature(obj)
    rig = rig or rig_cache.rig_of(obj)
    settings = settings_of(obj, options)
    keep_hands = options.keep_hand_orientation
    keep_hands = obj.fullbody_adjust.keep_hand_orientation if keep_hands is None else keep_hands

    # Read and check everything before anything is changed, so a bad input leaves the file as it was.
    progress("reading", 0.0)
    if apply_pose:
        # The current frame as the user sees it. Stepping to it with frame_set would evaluate the animation
        # again and throw away pose changes not keyed yet, even when the run then fails.
        goals = _current_targets(obj, context, options.skip_missing_targets)
        corners = (obstacles.obstacle_boxes(obj, context) if corners is None else corners)[None]
        snapshot = pose.as_batch(pose.read_pose(obj, rig.static(obj)) if start is None else start)
    else:
        with _pose_kept(obj):  # stepping through the frames evaluates the animation into the pose bones
            target_at = targets.target_frame_reader(obj, context)
            boxes_at = obstacles.box_frame_reader(obj, context)
            goal_rows, corner_rows = [], []

            def read_others(row, frame):  # one pass over the frames reads pose, targets and obstacles
                progress("reading", 0.3 * row / len(frames))
                goal_rows.append(target_at(frame))
                corner_rows.append(boxes_at(frame))

            snapshot = pose.read_pose_frames(obj, frames, each_frame=read_others)
            goals = targets.FrameTargets(*(np.stack(field) for field in zip(*goal_rows)))
            corners = np.stack(corner_rows)
    world_targets = goals.positions  # (F,E,3), NaN: no target
    bone_map, model = rig.bone_map, rig.model
    controlled = rig.controlled
    if controlled:  # solved on the metarig's hierarchy of the ORG- bones, as the model is
        snapshot = snapshot.derived("skeleton", lambda: replace(snapshot, parents=model.parents), of=model)
    else:
        _check_not_driven(obj, bone_map)
    # What depends on the start pose alone is checked and derived once per snapshot (Live solves from one
    # snapshot until its frame or base pose changes).
    snapshot.derived("checked", lambda: _check_start(obj, model, snapshot), of=model)
    _check_target_distances(obj, world_targets, snapshot)
    priorities = _priorities(obj)
    progress("solving", 0.3)

    to_solve, heads, tails, unit = snapshot.derived("solve space", lambda: _solve_space(snapshot, rig.ends), of=rig)
    arm_targets = _apply(to_solve, world_targets)
    end_turns, poles = _end_goals(model, snapshot, goals, to_solve)
    solve_settings = _in_solve_units(settings, snapshot.derived("object scales", lambda: _object_scales(snapshot)),
                                     unit)
    boxes = None
    if corners.shape[1]:  # a set's meshes far from the character are left out before they are built into boxes
        # Each limb keeps its mesh's radius plus the margin from the boxes (limb_thickness; none without a mesh).
        solve_settings = replace(solve_settings, clearance=limb_thickness.limb_clearances(
            obj, rig, unit, solve_settings.chain.margin))
        centre, radius = body_reach(model, heads, tails, arm_targets,
                                    snapshot.derived("skeleton reach", lambda: skeleton_reach(model, heads, tails),
                                                     of=model))
        pad = max([solve_settings.chain.margin] + [clearance for _limb, clearance in solve_settings.clearance])
        boxes = _armature_boxes(corners, to_solve, centre, radius + pad)
    try:
        hinges = snapshot.derived("hinge axes", lambda: ik_limits.hinge_hints(model, snapshot.rest_matrices,
                                                                             snapshot.pose_matrices), of=model)
        limits = ik_limits.joint_limits(obj, model, heads, tails, snapshot.pose_matrices, settings,
                                        controls=rig.fk_controls, hinge_axes=hinges)
        served = _served(obj, model, world_targets)
        result = solve_frames(model, heads, tails, arm_targets[:, served], _columns(targets.EFFECTORS, served),
                              priorities[served], obstacles=boxes, settings=solve_settings,
                              bone_x_axes=hinges, limits=limits,
                              end_turns=None if end_turns is None else end_turns[:, served],
                              poles=None if poles is None else poles[:, served])
    except SolverInputError as ex:
        raise AdjustError(f"Cannot adjust '{obj.name}': {ex}") from None
    status, reasons = (_widened(values, served, fill) for values, fill in
                       ((result.status, UNCONSTRAINED), (result.reasons, "no target on this frame")))
    progress("writing", 0.8)

    oriented = goals.oriented.any(axis=0)  # (E,) effectors that take their target's orientation
    written = _bones_to_write(model, snapshot, result, unit, keep_hands, oriented)
    names = tuple(snapshot.names[j] for j in written)
    action = None
    if controlled and names:
        channels = _control_channels(context, obj, frames, snapshot, result, unit, bone_map, keep_hands, oriented,
                                     solve_settings.chain.tolerance / float(unit.max()), apply_pose)
        names = tuple(channels)
        if options.insert_keys and names:
            action = keyframes.key_bones_frames(obj, None, frames, channels, action_name=options.new_action)
    elif names:
        # Both writers check all their input before writing any of it; the channels come from the snapshot
        # just read, so once keying has started the pose write cannot fail.
        channels = pose.armature_rotations_to_channels(obj, snapshot,
                                                       _new_pose_matrices(snapshot, result, unit, written), names)
        if options.insert_keys:
            action = keyframes.key_bones_frames(obj, None, frames, channels, action_name=options.new_action)
        if apply_pose:
            pose.apply_channels(obj, {bone: {prop: v[0] for prop, v in props.items()}
                                      for bone, props in channels.items()})
    progress("done", 1.0)

    if apply_pose and options.evaluated_residuals:
        # What the user sees is the pose Blender evaluates from the written channels (float32, constraints):
        # report the residuals of that pose rather than the solver's.
        heads = np.full((1, len(model.names), 3), np.nan)  # only the effectors' are read
        ends = [limb.end_bone for limb in model.limbs.values() if limb.effector in targets.EFFECTORS]
        heads[0, ends] = pose.evaluated_heads(obj, [model.names[j] for j in ends])
        world_effectors = _effector_positions(model, heads, np.eye(4)[None])
    else:
        world_effectors = _effector_positions(model, _armature_units(result.heads, unit), snapshot.matrix_world)
    residuals = norm(world_effectors - world_targets)
    return Outcome(frames=np.asarray(frames, dtype=np.float64), effectors=tuple(targets.EFFECTORS),
                   residuals=residuals, status=status, reasons=reasons, moved_bones=names,
                   count_penetrations=lambda: _penetrations(model, result.heads, result.tails, boxes), action=action)


def _new_pose_matrices(snapshot, result, unit, bones):
    """Armature-space matrices (F,k,4,4) of ``bones`` in the solved pose (their scale kept); ``unit`` (F,): the
    solve space's length of one armature unit (_solve_space)."""
    new_pose = np.zeros(snapshot.pose_matrices[:, bones].shape)
    new_pose[..., :3, :3] = result.rotations[:, bones] @ snapshot.pose_matrices[:, bones, :3, :3]
    new_pose[..., :3, 3] = _armature_units(result.heads[:, bones], unit)
    new_pose[..., 3, 3] = 1.0
    return new_pose


def _control_channels(context, obj, frames, snapshot, result, unit, bone_map, keep_hands, oriented, tolerance,
                      apply_pose):
    """A control rig's solved pose as its controls' channels {control: {property: (F,k)}}: on each frame the
    controls are placed so the mapped bones reach the solve (control_match), and the controls that moved on some
    frame are returned. With ``apply_pose`` (one frame, the current one) the controls are left placed; otherwise
    every frame is stepped to and the pose is put back afterwards."""
    names = [bone for _group, bone in bone_map.items()]
    mapped = snapshot.indices(names)
    desired = _new_pose_matrices(snapshot, result, unit, mapped)
    if not keep_hands:  # the hands and feet keep their pose relative to the forearm and shin (as _bones_to_write)
        old = snapshot.pose_matrices[:, mapped]
        position = {name: k for k, name in enumerate(names)}
        for end, limb in (("hand.L", "arm.L"), ("hand.R", "arm.R"), ("foot.L", "leg.L"), ("foot.R", "leg.R")):
            if oriented[targets.EFFECTORS.index(end)]:
                continue  # ... but one that takes its target's orientation
            k, p = position[bone_map.bones(end)[0]], position[bone_map.bones(limb)[-1]]
            desired[:, k] = desired[:, p] @ pose.affine_inverse(old[:, p]) @ old[:, k]
    pairs = control_rig.control_pairs(obj, bone_map)
    if apply_pose:
        return control_channels(obj, context.view_layer, pairs, names, desired, tolerance, [0], start=snapshot)
    with _pose_kept(obj):
        rows = (row for row, _frame in frames_module.step_frames(context.scene, frames))
        return control_channels(obj, context.view_layer, pairs, names, desired, tolerance, rows, start=snapshot)


def _in_solve_units(settings, scales, unit):
    """``settings`` (world units) for a solve in the solve space (_solve_space): the tolerance shrunk by the
    largest object scale, so a target met in the solve space is met in the world; the obstacle margin grown by
    the smallest, so the clearance kept in the world is at least the margin. Under a uniform object scale both
    stay as they are. ``scales``: _object_scales; ``unit`` (F,): _solve_space's."""
    largest, smallest = scales
    chain = settings.chain
    chain = replace(chain, tolerance=chain.tolerance * float(unit.min()) / largest,
                    margin=chain.margin * float(unit.max()) / smallest)
    return replace(settings, chain=chain)


def _object_scales(snapshot):
    """(largest, smallest) axis scale of the object's world matrix over the snapshot's frames."""
    scales = norm(np.swapaxes(snapshot.matrix_world[:, :3, :3], -1, -2))  # (F,3)
    return float(scales.max()), float(scales.min())


def _solve_space(snapshot, ends):
    """(to_solve (F,4,4), heads, tails (F,B,3), unit (F,)), read-only (they are kept with the snapshot): the solve
    runs in the armature's space scaled by ``unit``, the world length of one armature unit (the cube root of the
    object scale's volume), so that bone lengths are rigid there even under a non-uniform object scale, while every
    distance the solver reports (residuals, reaches, in its reasons) is in world units: an armature in centimetres
    under an object scale of 0.01 is solved in metres. The tails are where the bones end as joints (``ends``,
    rig_cache.Rig.ends), not where the importer left them."""
    unit = np.cbrt(np.linalg.det(snapshot.matrix_world[:, :3, :3]))
    to_solve = unit[:, None, None] * pose.affine_inverse(snapshot.matrix_world)
    to_solve[:, 3] = (0.0, 0.0, 0.0, 1.0)
    out = (to_solve, _apply(to_solve, snapshot.heads),
           unit[:, None, None] * end_points(snapshot.pose_matrices, ends), unit)
    for array in out:
        array.flags.writeable = False
    return out


def _check_start(obj, model, snapshot):
    """AdjustError unless the start pose can be solved from (object scale, bones' lengths and scales)."""
    _check_object_scale(obj, snapshot)
    _check_driven_bones(model, snapshot)
    return True


@contextmanager
def _pose_kept(obj):
    """Put the pose bones' channels back as they were on leaving (also on error): a frame change evaluates the
    animation into them, which would throw away what the user posed at the current frame and has not keyed."""
    bones = obj.pose.bones
    saved = {prop: _channel_values(bones, prop, size) for prop, size in pose.CHANNEL_SIZES.items()}
    try:
        yield
    finally:
        for prop, size in pose.CHANNEL_SIZES.items():
            now = _channel_values(bones, prop, size)
            for index in np.nonzero(np.any(now != saved[prop], axis=1))[0]:
                setattr(bones[int(index)], prop, saved[prop][index].tolist())  # RNA set: tags the update


def _channel_values(bones, prop, size):
    values = np.empty(len(bones) * size, dtype=np.float32)
    bones.foreach_get(prop, values)
    return values.reshape(-1, size)


def _check_not_driven(obj, bone_map):
    problem = driven_problem(obj, bone_map)
    if problem:
        raise AdjustError(problem)


def driven_problem(obj, bone_map):
    """On a rig this extension does not know as a control rig, a mapped bone that follows a constraint would
    override the keys written to it: the one line saying so, or None. Limit constraints only bound the pose."""
    for _group, name in bone_map.items():
        pose_bone = obj.pose.bones.get(name)
        for con in pose_bone.constraints if pose_bone is not None else ():
            if con.enabled and con.influence > 0.0 and not con.type.startswith("LIMIT_"):
                return (f"Bone '{name}' of '{obj.name}' follows its constraint '{con.name}', which would override "
                        f"keys written to it: pose the controls that drive it, or map other bones")
    return None


def rig_summary(obj):
    """(line, ok) for the panel: what kind of rig ``obj`` is and what Adjust Pose keys on it, or why keys on
    its mapped bones would not hold. None before the rig is mapped."""
    if control_rig.is_generated_rigify(obj):
        return control_rig.describe(obj), True
    bone_map = mapping.load_map(obj)
    if bone_map is None or obj.pose is None:  # not mapped yet, or an armature never evaluated
        return None
    problem = driven_problem(obj, bone_map)
    return (problem, False) if problem else ("Keys the mapped bones", True)


def _check_target_distances(obj, world_targets, snapshot):
    """A target further from the rig than _FAR times its size is an error, not a goal: Blender's float32
    positions cannot place anything that far to better than a tenth of the rig (typing inf into a location
    field stores the largest float, 3.4e38)."""
    distance = norm(world_targets - snapshot.heads[:, :1])  # (F,E), NaN: no target
    far = np.nonzero((distance > _FAR * _world_size(snapshot)).any(axis=0))[0]
    if len(far):
        effector = targets.EFFECTORS[far[0]]
        name = next(s.target.name for s in obj.fullbody_adjust.targets if s.enabled and s.effector == effector)
        raise AdjustError(f"Target '{name}' for {effector} is {np.nanmax(distance[:, far[0]]):.3g} units away, "
                          f"too far to reach for (a location set to inf?)")


def _current_targets(obj, context, skip_missing=False):
    """FrameTargets (one frame: (1,E,...) each) of the enabled targets at the current frame as evaluated."""
    specs = targets.read_targets(obj, context.evaluated_depsgraph_get(), skip_missing=skip_missing)
    return targets.FrameTargets(*(field[None] for field in targets.frame_targets(specs)))


def _end_goals(model, snapshot, goals, to_arm):
    """The solver's end_turns (F,E,3,3) and poles (F,E,3) in armature space from the FrameTargets (None where
    no slot asks for them): a hand or foot with use_rotation turns from its pose orientation to its target's."""
    end_turns = None
    if goals.oriented.any():
        end_turns = np.full(goals.rotations.shape, np.nan)
        for limb in model.limbs.values():
            if limb.effector not in targets.EFFECTORS:
                continue
            column = targets.EFFECTORS.index(limb.effector)
            rows = goals.oriented[:, column] & np.isfinite(goals.positions[:, column, 0])
            if rows.any():
                wanted = _orthonormal(to_arm[rows, :3, :3] @ goals.rotations[rows, column])
                now = _orthonormal(snapshot.pose_matrices[rows, limb.end_bone, :3, :3])
                end_turns[rows, column] = wanted @ np.swapaxes(now, -1, -2)
    poles = _apply(to_arm, goals.poles) if np.isfinite(goals.poles).any() else None
    return end_turns, poles


def _orthonormal(matrices):
    """The rotations (...,3,3) nearest ``matrices`` (their polar factor): a rotation carried through a scaled
    armature transform, or a bone's pose matrix without its scale."""
    u, _s, vt = np.linalg.svd(matrices)
    return u @ vt


def _served(obj, model, world_targets):
    """Columns of the EFFECTORS the model can serve (the head only with neck bones mapped); AdjustError naming the
    slot when an enabled target asks for one it cannot."""
    served = [k for k, effector in enumerate(targets.EFFECTORS) if effector in model.effectors]
    for k, effector in enumerate(targets.EFFECTORS):
        if k not in served and np.isfinite(world_targets[:, k]).any():
            raise AdjustError(f"The {effector} target of '{obj.name}' needs neck bones mapped below the head: "
                              f"map them in Bone Mapping, or switch the {effector} slot off")
    return served


def _columns(values, served):
    return tuple(values[k] for k in served)


def _widened(values, served, fill):
    """(F,k) values of the served effectors as (F,E), ``fill`` for the others."""
    out = np.full(values.shape[:1] + (len(targets.EFFECTORS),), fill, dtype=object)
    out[:, served] = values
    return out.astype(str)


def _priorities(obj):
    by_effector = {slot.effector: int(slot.priority) for slot in obj.fullbody_adjust.targets}
    return np.array([by_effector.get(e, targets.DEFAULT_PRIORITY[e]) for e in targets.EFFECTORS], dtype=np.float64)


def _check_object_scale(obj, snapshot):
    """A mirrored or flattened object transform (on some frame, or through a parent) cannot be solved in."""
    det = np.linalg.det(snapshot.matrix_world[:, :3, :3])
    if (det <= 0.0).any():
        frame = snapshot.frame[int(np.argmax(det <= 0.0))]
        raise AdjustError(f"Armature '{obj.name}' has a negative or zero scale at frame {frame:g}: "
                          f"fix its scale first")


def _check_driven_bones(model, snapshot):
    """Each bone the solver may move, and each parent it is posed relative to, needs a length and an
    invertible pose matrix: a bone scaled to 0 in Pose Mode (on any axis) has neither."""
    driven = _driven(model.roles, with_ends=True)
    needed = driven.copy()
    needed[snapshot.parents[driven & (snapshot.parents >= 0)]] = True
    needed = np.nonzero(needed)[0]  # only these are measured (a fraction of a full rig's bones)
    axis_scales = norm(np.swapaxes(snapshot.pose_matrices[:, needed, :3, :3], -1, -2))  # (F,k,3)
    flat = (axis_scales.min(axis=-1) <= _FLAT) | (snapshot.lengths[:, needed] <= _FLAT * _world_size(snapshot))
    bad = needed[flat.any(axis=0)]
    if len(bad):
        raise AdjustError(f"Bone '{snapshot.names[bad[0]]}' has zero length or scale (scaled to 0 in Pose Mode?): "
                          f"fix it before adjusting")


def _driven(roles, with_ends):
    """(J,) bool: the bones the solver moves (root and chain bones; with_ends also hands, feet and head). By
    comparisons: np.isin costs ~0.1 ms a call, a fair part of a Live update's reading."""
    mask = (roles == ROOT) | (roles == CHAIN)
    return mask | (roles == END) if with_ends else mask


def _world_size(snapshot):
    """The rig's size in the world (_size of its heads), kept with the snapshot."""
    return snapshot.derived("world size", lambda: _size(snapshot.heads))


def _size(points):
    """The rig's size: the largest extent of its points (..., 3) along an axis."""
    return max(float(np.ptp(points.reshape(-1, 3), axis=0).max()), 1e-12)


def _apply(matrices, points):
    """points (F,...,3) through (F,4,4) matrices."""
    m = matrices.reshape(matrices.shape[0], *([1] * (points.ndim - 2)), 4, 4)
    return np.einsum("...ij,...j->...i", m[..., :3, :3], points) + m[..., :3, 3]


def _armature_boxes(world_corners, to_arm, centre, radius):
    """The obstacles' boxes in armature space from their world corners (F,K,8,3) in bound_box order: each the
    mesh's own (oriented) box, as the user sees it; None when there are none. Boxes no bone can reach (outside the
    ball `centre` (F,3), `radius` (F,) on every frame: solver.obstacle_reach) are left out before they are built:
    a box built from 8 corners lies within sqrt(3) times their farthest distance from their mean (along each of its
    axes it spans their projections), so one whose ball is outside is outside. (The solver then leaves out, on the
    built boxes' bounds, what this looser test kept.)

    One frame's last corners and boxes are kept (_last_boxes): Live builds the same boxes on every update while
    only the targets move, and so do clicks while the obstacles stay."""
    one = world_corners.shape[0] == 1
    last = _last_boxes if one else {}  # a frame range's are built for its one solve
    key = (to_arm.tobytes(), world_corners.shape, world_corners.tobytes()) if one else None
    if key is None or last.get("key") != key:
        corners = _apply(to_arm, world_corners)
        mean = corners.mean(axis=2)
        last.clear()
        size = np.sqrt(3.0) * norm(corners - mean[:, :, None]).max(axis=2)
        last.update(key=key, corners=corners, mean=mean, size=size)
    keep = (norm(last["mean"] - centre[:, None]) - last["size"] <= radius[:, None]).any(axis=0)
    if not keep.any():
        return None
    if last.get("kept") is None or not np.array_equal(last["kept"], keep):
        last.update(kept=keep, boxes=Boxes.from_box_corners(last["corners"][:, keep]))
    return last["boxes"]


# _armature_boxes' last frame: its key (the armature transform and the world corners, as bytes), the corners in
# armature space with their means and sizes, and the Boxes built from those kept (immutable: shared by the solves).
_last_boxes = {}


def _bones_to_write(model, snapshot, result, unit, keep_hands, oriented):
    """Indices of the bones the solver drives whose transform changed on some frame, or below one that did (a
    foot that keeps its world orientation while its shin turns changes its local rotation), parents first.
    ``oriented`` (E,) bool: effectors whose end bone takes its target's orientation, written even without
    ``keep_hands``."""
    driven = _driven(model.roles, with_ends=keep_hands)
    for limb in model.limbs.values():
        if limb.effector in targets.EFFECTORS and oriented[targets.EFFECTORS.index(limb.effector)]:
            driven[limb.end_bone] = True
    driven = np.nonzero(driven)[0]  # only these are measured (a fraction of a full rig's bones)
    turn = np.abs(result.rotations[:, driven] - np.eye(3)).max(axis=(-1, -2))  # (F,k)
    old_heads = snapshot.pose_matrices[..., :3, 3]
    shift = norm(_armature_units(result.heads[:, driven], unit) - old_heads[:, driven])
    shift = shift / snapshot.derived("armature size", lambda: _size(old_heads))
    changed = np.zeros(len(model.names), dtype=bool)
    changed[driven[((turn > _MOVED) | (shift > _MOVED)).any(axis=0)]] = True
    below = np.zeros(len(model.names), dtype=bool)  # some ancestor changed
    for bone in model.order.tolist():
        parent = int(model.parents[bone])
        below[bone] = parent >= 0 and (changed[parent] or below[parent])
    return driven[changed[driven] | below[driven]]


def _armature_units(points, unit):
    """Solve-space points (F,...,3) in armature units (_solve_space's ``unit`` (F,))."""
    return points / unit.reshape((-1,) + (1,) * (points.ndim - 1))


def _effector_positions(model, heads, matrix_world):
    """World positions (F,E,3) of the effector joints (the heads of the hand, foot and head bones)."""
    out = np.full(heads.shape[:1] + (len(targets.EFFECTORS), 3), np.nan)
    for limb in model.limbs.values():
        if limb.effector in targets.EFFECTORS:
            out[:, targets.EFFECTORS.index(limb.effector)] = heads[:, limb.end_bone]
    return _apply(matrix_world, out)


def _penetrations(model, heads, tails, boxes):
    """Chain joints inside, and chain segments crossing, an obstacle box: (F,) counts each. Every limb's chain in
    one test (the counts add up over joints and segments, so they are the sums of the limbs' own)."""
    if boxes is None:
        none = np.zeros(heads.shape[0], dtype=np.int64)
        return none, none
    chains = [limb.joints(heads, tails) for limb in model.limbs.values()]
    segments, at = [], 0
    for chain in chains:
        n = chain.shape[1]
        segments.append(np.c_[np.arange(at, at + n - 1), np.arange(at + 1, at + n)])
        at += n
    return penetrations(np.concatenate(chains, axis=1), np.concatenate(segments), boxes)


def create_targets(context, obj, *, reset=False):
    """Empties at the current wrists and ankles (and head, when mapped), linked in the armature's target slots.
    Returns {effector: empty}."""
    check_armature(obj)
    bone_map = mapping.ensure_map(obj)
    snapshot = pose.read_pose(obj)
    positions = {}
    for effector in targets.EFFECTORS:
        bones = bone_map.bones(effector)  # the hand, foot and head groups are named after their effectors
        if bones:
            positions[effector] = snapshot.heads[snapshot.index(bones[-1])]
    size = 0.04 * max(float(np.ptp(snapshot.heads, axis=0).max()), 1e-3)
    targets.ensure_slots(obj)
    return targets.create_targets(context, obj, positions, size, reset=reset)
