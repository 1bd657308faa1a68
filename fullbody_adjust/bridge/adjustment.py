"""The one way through: active armature → bone mapping → targets and obstacles → the solver → bone channels
→ keyframes. Operators and the command line call only ``adjust_pose`` and ``adjust_frames`` here.

The solve runs in the armature's own space (its object transform undone) scaled to world units (reading/solve_space.py):
bone lengths are rigid there even under non-uniform object scale, targets map into it exactly, every distance
the solver reports is in world units, and each obstacle is its mesh's bounding box with the mesh's rotation (an
oriented box) carried into it. What is checked before anything changes is reading/start_checks.py's; what a run did,
outcome.py's.
"""

from contextlib import contextmanager
from dataclasses import dataclass, replace

import numpy as np

from ..solver import ChainSettings, SolverInputError
from ..solver.fullbody.adjust import AdjustSettings, adjust_frames as solve_frames
from ..solver.fullbody.settings import UNCONSTRAINED
from ..solver.maths.geometry import affine_inverse, norm
from ..solver.obstacles.reach import body_reach, skeleton_reach
from .rig import control_rig, rig_cache, targets
from .reading import effectors, frames as frames_module, goals as goals_of, ik_limits, limb_thickness, obstacles, pose
from .reading import solve_space, start_checks
from .writing import keyframes, solved_pose
from .writing.channels import apply_channels, armature_rotations_to_channels
from .rig.control_frames import control_channels
from .errors import AdjustError
from .outcome import Outcome


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
    start_checks.check_armature(obj)
    rig = rig or rig_cache.rig_of(obj)
    settings = settings_of(obj, options)
    keep_hands = options.keep_hand_orientation
    keep_hands = obj.fullbody_adjust.keep_hand_orientation if keep_hands is None else keep_hands

    # Read and check everything before anything is changed, so a bad input leaves the file as it was.
    progress("reading", 0.0)
    if apply_pose:
        # The current frame as the user sees it. Stepping to it with frame_set would evaluate the animation
        # again and throw away pose changes not keyed yet, even when the run then fails.
        goals = goals_of.current_targets(obj, context, options.skip_missing_targets)
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
        start_checks.check_not_driven(obj, bone_map)
    # What depends on the start pose alone is checked and derived once per snapshot (Live solves from one
    # snapshot until its frame or base pose changes).
    snapshot.derived("checked", lambda: start_checks.check_start(obj, model, snapshot), of=model)
    start_checks.check_target_distances(obj, world_targets, snapshot)
    priorities = goals_of.priorities(obj)
    progress("solving", 0.3)

    to_solve, heads, tails, unit = snapshot.derived("solve space", lambda: solve_space.solve_space(snapshot, rig.ends),
                                                    of=rig)
    arm_targets = solve_space.transform(to_solve, world_targets)
    end_turns, poles = goals_of.end_goals(obj, model, snapshot, goals, to_solve)
    scales = snapshot.derived("object scales", lambda: solve_space.object_scales(snapshot))
    solve_settings = solve_space.in_solve_units(settings, scales, unit)
    boxes = None
    if corners.shape[1]:  # a set's meshes far from the character are left out before they are built into boxes
        # Each limb keeps its mesh's radius plus the margin from the boxes (limb_thickness; none without a mesh).
        # Their surfaces as points on their segments pick, among the poses that meet a target, one that keeps the
        # mesh itself out (limb_easing).
        solve_settings = replace(solve_settings, clearance=limb_thickness.limb_clearances(
            obj, rig, unit, solve_settings.chain.margin), surface=limb_thickness.limb_surfaces(
            obj, rig, snapshot.matrices, to_solve))
        centre, radius = body_reach(model, heads, tails, arm_targets,
                                    snapshot.derived("skeleton reach", lambda: skeleton_reach(model, heads, tails),
                                                     of=model))
        pad = max([solve_settings.chain.margin] + [clearance for _limb, clearance in solve_settings.clearance])
        boxes = solve_space.armature_boxes(corners, to_solve, centre, radius + pad)
    try:
        hinges = snapshot.derived("hinge axes", lambda: ik_limits.hinge_hints(
            model, snapshot.rest_matrices, snapshot.pose_matrices, rig.rest_hinges), of=model)
        limits = ik_limits.joint_limits(obj, model, heads, tails, snapshot.pose_matrices, settings,
                                        controls=rig.fk_controls, hinge_axes=hinges)
        served = goals_of.served(obj, model, world_targets)
        result = solve_frames(model, heads, tails, arm_targets[:, served],
                              goals_of.columns(targets.EFFECTORS, served),
                              priorities[served], obstacles=boxes, settings=solve_settings,
                              bone_x_axes=hinges, limits=limits,
                              end_turns=None if end_turns is None else end_turns[:, served],
                              poles=None if poles is None else poles[:, served])
    except SolverInputError as ex:
        raise AdjustError(f"Cannot adjust '{obj.name}': {ex}") from None
    status, reasons = (goals_of.widened(values, served, fill) for values, fill in
                       ((result.status, UNCONSTRAINED), (result.reasons, "no target on this frame")))
    progress("writing", 0.8)

    oriented = goals.oriented.any(axis=0)  # (E,) effectors that take their target's orientation
    written = solved_pose.bones_to_write(model, snapshot, result, unit, keep_hands, oriented)
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
        channels = armature_rotations_to_channels(obj, snapshot,
                                                  solved_pose.new_pose_matrices(snapshot, result, unit, written), names)
        if options.insert_keys:
            action = keyframes.key_bones_frames(obj, None, frames, channels, action_name=options.new_action)
        if apply_pose:
            apply_channels(obj, {bone: {prop: v[0] for prop, v in props.items()}
                                 for bone, props in channels.items()})
    progress("done", 1.0)

    if apply_pose and options.evaluated_residuals:
        # What the user sees is the pose Blender evaluates from the written channels (float32, constraints):
        # report the residuals of that pose rather than the solver's.
        heads = np.full((1, len(model.names), 3), np.nan)  # only the effectors' are read
        tails = heads.copy()  # ... and a hand-less arm's last bone's end (its wrist)
        limbs = [limb for limb in model.limbs.values() if limb.effector in targets.EFFECTORS]
        ends = [limb.end_bone for limb in limbs if limb.end_bone is not None]
        heads[0, ends] = pose.evaluated_heads(obj, [model.names[j] for j in ends])
        wrists = [limb.bones[-1] for limb in limbs if limb.end_bone is None]
        if wrists:
            tails[0, wrists] = effectors.evaluated_ends(obj, rig, wrists)
        world_effectors = effectors.effector_positions(model, heads, tails, np.eye(4)[None])
    else:
        world_effectors = effectors.effector_positions(model, solve_space.armature_units(result.heads, unit),
                                              solve_space.armature_units(result.tails, unit), snapshot.matrix_world)
    residuals = norm(world_effectors - world_targets)
    return Outcome(frames=np.asarray(frames, dtype=np.float64), effectors=tuple(targets.EFFECTORS),
                   residuals=residuals, status=status, reasons=reasons, moved_bones=names,
                   count_penetrations=lambda: effectors.penetrations(model, result.heads, result.tails, boxes),
                   action=action)


def _control_channels(context, obj, frames, snapshot, result, unit, bone_map, keep_hands, oriented, tolerance,
                      apply_pose):
    """A control rig's solved pose as its controls' channels {control: {property: (F,k)}}: on each frame the
    controls are placed so the mapped bones reach the solve (control_match), and the controls that moved on some
    frame are returned. With ``apply_pose`` (one frame, the current one) the controls are left placed; otherwise
    every frame is stepped to and the pose is put back afterwards."""
    names = [bone for _group, bone in bone_map.items()]
    mapped = snapshot.indices(names)
    desired = solved_pose.new_pose_matrices(snapshot, result, unit, mapped)
    if not keep_hands:  # the hands and feet keep their pose relative to the forearm and shin (as _bones_to_write)
        old = snapshot.pose_matrices[:, mapped]
        position = {name: k for k, name in enumerate(names)}
        for end, limb in (("hand.L", "arm.L"), ("hand.R", "arm.R"), ("foot.L", "leg.L"), ("foot.R", "leg.R")):
            if oriented[targets.EFFECTORS.index(end)] or not bone_map.bones(end):
                continue  # ... but one that takes its target's orientation (or is not mapped: no hand bone)
            k, p = position[bone_map.bones(end)[0]], position[bone_map.bones(limb)[-1]]
            desired[:, k] = desired[:, p] @ affine_inverse(old[:, p]) @ old[:, k]
    pairs = control_rig.control_pairs(obj, bone_map)
    if apply_pose:
        return control_channels(obj, context.view_layer, pairs, names, desired, tolerance, [0], start=snapshot,
                                evaluated=True)  # current_targets had the scene evaluated; nothing changed since
    with _pose_kept(obj):
        rows = (row for row, _frame in frames_module.step_frames(context.scene, frames))
        return control_channels(obj, context.view_layer, pairs, names, desired, tolerance, rows, start=snapshot)


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
