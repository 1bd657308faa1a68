"""Retarget a source armature's motion (e.g. an imported BVH) onto a target armature of other proportions
(issue 6, part 2; paper §6.2.3). The operator and the command line call only ``retarget`` here.

    read   the source's action: its F-Curves read with foreach_get and evaluated at the frames in numpy
           (exactly at keys; F-Curve.evaluate between keys), forward kinematics in numpy. When something
           besides the action moves the bones (NLA, drivers, constraints, an animated or parented object,
           bones that do not inherit plainly) the evaluated pose is read frame by frame instead;
    plan   solver.retarget: rotations through both bone mappings, root and effector trajectories scaled by
           the leg-length ratio and turned to the target's heading, the source's contacts (floor, contact
           objects' boxes, raised supports) found and held, the whole body shifted (smoothly) where a limb
           could not reach its target (solver/retarget.py says exactly how);
    solve  solver.adjust.adjust_frames, one vectorised batch over every frame, in the target's armature space,
           over its mapped bones and their ancestors, with the target's stored solver settings and each elbow
           and knee hinge fixed in its upper bone (solver.retarget.motion_limits: no pops as a limb straightens);
    write  every mapped target bone's rotation (and the root's location), one foreach_set per F-Curve, into a
           NEW action assigned to the target. The source and its action are only read, never changed; the
           target's previous action, if it has no other user, gets a fake user so it is kept.
    measure how the result keeps the source's contacts, on its own bones (solver.retarget_metrics).
"""

from dataclasses import dataclass
import re

import bpy
import numpy as np

from ..solver import SolverInputError
from ..solver import retarget as rt
from ..solver.adjust import adjust_frames as solve_frames
from . import adjustment, control_rig, ik_limits, keyframes, mapping, pose, targets
from .control_match import control_channels
from .errors import AdjustError

_BONE_PATH = re.compile(r'^pose\.bones\["((?:[^"\\]|\\.)*)"\]\.(\w+)$')
_SAME_FRAME = 1e-4  # a key this close to a frame is at it (keys are float32)


@dataclass
class RetargetOutcome:
    """What a retarget did, world units. Per frame and effector (solver.retarget.EFFECTORS order):
    targets, residuals (effector -> target distance after the solve), status, contacts (held frames).
    contact_report: how the result keeps the source's contacts, measured on its own bones
    (solver.retarget_metrics.contact_figures: per effector contact error, sliding, frames below the floor,
    pops; 'before' the same of the transferred motion before the adjustment, 'source' of the source);
    contact_error (F,E): the result's contact error on contact frames, NaN elsewhere."""

    action: object
    frames: np.ndarray  # (F,)
    effectors: tuple
    targets: np.ndarray  # (F,E,3)
    residuals: np.ndarray  # (F,E)
    status: np.ndarray  # (F,E) str
    contacts: np.ndarray  # (F,E) bool
    leg_ratio: float
    read_from: str  # 'F-Curves' | 'frame by frame'
    keyed_bones: tuple
    contact_report: dict = None
    contact_error: np.ndarray = None
    contact_error_before: np.ndarray = None

    def contacts_not_held(self):
        """Frames (summed over effectors) where a contact within reach is not held on the result."""
        return sum(f["not_held_frames"] for f in (self.contact_report or {}).get("effectors", {}).values())

    def summary(self):
        """One line for the operator's report and the command line."""
        met = int(np.sum(self.status == "reached"))
        total = self.status.size
        found = (self.contact_report or {}).get("effectors", {})
        held = ", ".join(f"{e} {int(self.contacts[:, k].sum())}" for k, e in enumerate(self.effectors)
                         if self.contacts[:, k].any())
        line = (f"Retargeted {len(self.frames)} frames into '{self.action.name}' (leg ratio "
                f"{self.leg_ratio:.3g}): {met} of {total} effector targets met, largest residual "
                f"{float(np.max(self.residuals)):.3g}; contact frames held: {held or 'none'}")
        if found:
            line += (f"; below the floor on {sum(f['frames_below_floor'] for f in found.values())} frames, "
                     f"{sum(f['pops'] for f in found.values())} pops, "
                     f"{self.contacts_not_held()} contact frames not held")
        return line


def retarget(context, source_obj, target_obj, frame_start=None, frame_end=None, *, contacts=("ground",),
             exact=True, new_action=None, floor=None, progress=None):
    """Retarget ``source_obj``'s motion over [frame_start, frame_end] (default: its action's frame range)
    onto ``target_obj``, into a new action named ``new_action`` (default '<source action>_<target>').

    contacts: what hands and feet may touch, as ``contact_specs`` reads it: 'ground' (planted feet rest on
    the floor, still) and any number of ('object', Object or name) (hands and feet touching the object's box
    are held on it; feet still off the floor stand on something raised). exact: hands on objects at the
    source's own world positions (else scaled like the motion). ``floor``: world height the source's ground is
    moved to (None: where it is). Returns a RetargetOutcome; AdjustError (one
    line) on bad input, before anything changes (but the bone map stored on the target, see
    mapping.ensure_map)."""
    progress = progress or (lambda stage, fraction: None)
    progress("reading", 0.0)
    prepared = prepare(context, source_obj, target_obj, frame_start, frame_end, contacts=contacts, exact=exact,
                       floor=floor)
    target, plan = prepared.target, prepared.plan

    progress("solving", 0.2)
    try:
        model, bones = rt.body_model(target)
        start, heads, tails = plan.start_pose[:, bones], plan.heads[:, bones], plan.tails[:, bones]
        settings = adjustment.settings_of(target_obj)
        limits = rt.motion_limits(model, start, heads, tails, settings.human_limits) if settings.use_limits else None
        limits = ik_limits.joint_limits(target_obj, model, heads, tails, start, settings, defaults=limits)
        result = solve_frames(model, heads, tails, plan.targets, rt.EFFECTORS,
                              [targets.DEFAULT_PRIORITY[e] for e in rt.EFFECTORS], settings=settings, limits=limits)
    except SolverInputError as ex:
        raise AdjustError(f"Cannot retarget '{source_obj.name}' onto '{target_obj.name}': {ex}") from None

    progress("writing", 0.8)
    name = new_action or f"{_action_name(source_obj)}_{target_obj.name}"
    solved = rt.solved_pose(plan, result.rotations, result.heads, bones)
    action, keyed = write_pose(context, target_obj, target, solved, prepared.frames, name)
    progress("done", 1.0)

    ends = [model.groups[e][0] for e in rt.EFFECTORS]
    residuals = np.linalg.norm(target.to_world(result.heads[:, ends]) - plan.world_targets, axis=-1)
    reachable = {e: result.status[:, k] != "unreachable" for k, e in enumerate(rt.EFFECTORS)}
    report, after = _contact_report(prepared, solved, bones, reachable, context.scene)
    _, before = _contact_report(prepared, plan.start_pose, bones, None, context.scene)
    return RetargetOutcome(action=action, frames=prepared.frames, effectors=rt.EFFECTORS,
                           targets=plan.world_targets, residuals=residuals, status=result.status,
                           contacts=plan.contacts, leg_ratio=plan.leg_ratio, read_from=prepared.read_from,
                           keyed_bones=keyed, contact_report=report["report"], contact_error=after,
                           contact_error_before=before)


def _contact_report(prepared, pose, bones, reachable, scene):
    """The contact figures of a pose (F,J,4,4) of the target whose ``bones`` were solved (the others follow
    them as their channels say), against the source's contacts: ({'report': {...}}, (F,E) contact error)."""
    target, source, plan = prepared.target, prepared.source, prepared.plan
    posed = rt.carry_unsolved(target, pose, bones, prepared.target_basis)
    t_heads, t_tails = target.world_points(posed)
    s_heads, s_tails = source.world_points(prepared.source_pose)
    fps = scene.render.fps / scene.render.fps_base
    figures, curves = rt.contact_figures(
        plan.contact_list,
        {e: rt.effector_points(target, t_heads, t_tails, e) for e in rt.EFFECTORS},
        {e: rt.effector_points(source, s_heads, s_tails, e) for e in rt.EFFECTORS},
        plan.boxes, plan.ground, rt.leg_length(target), plan.leg_ratio, fps, reachable)
    objects = [name.split(" ", 1)[1] for name in prepared.contact_names if name.startswith("object ")]
    for e, found in plan.contact_list.items():  # each contact by frame number, and what it touches
        for listed, contact in zip(figures[e]["contacts"], found):
            listed.update(frame_start=_frame_number(prepared.frames[contact.start]),
                          frame_end=_frame_number(prepared.frames[contact.stop - 1]),
                          touches=objects[contact.box] if contact.box >= 0 else contact.kind)
    report = {"contacts": list(prepared.contact_names), "floor": plan.ground, "effectors": figures}
    return {"report": report}, np.stack([curves[e] for e in rt.EFFECTORS], axis=1)


@dataclass
class Prepared:
    """A retarget before its solve: both rigs (solver.retarget.Rig), the plan (start pose and targets), the
    frames, how the source was read, the source's pose (F,Js,4,4), the target's unmapped bases and the
    contacts asked for, by name."""

    source: object
    target: object
    plan: object
    frames: np.ndarray
    read_from: str
    source_pose: np.ndarray = None
    target_basis: np.ndarray = None
    contact_names: tuple = ()


def contact_specs(context, contacts):
    """(ground, [Object]) of what hands and feet may touch: 'ground', or ('object', Object or its name), one
    or several (a single str or pair alone is one). AdjustError (one line) on anything else."""
    if isinstance(contacts, str) or (isinstance(contacts, tuple) and len(contacts) == 2
                                     and str(contacts[0]).lower() == "object"):
        contacts = [contacts]
    ground, objects = False, []
    for spec in contacts or ():
        kind, name = (spec, None) if isinstance(spec, str) else (spec[0], spec[1] if len(spec) > 1 else None)
        kind = str(kind).lower()
        if kind == "ground":
            ground = True
        elif kind == "object":
            obj = bpy.data.objects.get(name) if isinstance(name, str) else name
            if obj is None:
                raise AdjustError(f"No contact object '{name}'" if name else
                                  "Contacts with an object need a contact object: name it")
            if obj not in objects:
                objects.append(obj)
        else:
            raise AdjustError(f"Unknown contacts '{kind}' (use ground or object)")
    return ground, objects


def prepare(context, source_obj, target_obj, frame_start=None, frame_end=None, *, contacts=("ground",),
            exact=True, floor=None):
    """Check the input, read the source's motion and plan the retarget (see ``retarget``); changes nothing
    but the target's stored bone map."""
    _check_source(source_obj)
    adjustment.check_armature(target_obj)
    if target_obj.mode == 'EDIT':
        raise AdjustError(f"'{target_obj.name}' is in Edit Mode: leave it to retarget onto it")
    if source_obj == target_obj:
        raise AdjustError("Source and target are the same armature: pick another source")
    ground, objects = contact_specs(context, contacts)
    boxes = _contact_boxes(context, objects) if objects else None
    frames = _frames(source_obj, frame_start, frame_end)
    anim = target_obj.animation_data
    if anim is not None and anim.use_tweak_mode:
        raise AdjustError(f"'{target_obj.name}' is in NLA tweak mode: leave it to retarget onto it")

    source_map = _source_map(source_obj)
    target_map = mapping.ensure_map(target_obj)
    scene = context.scene
    try:
        source = _rig(source_obj, source_map)
        target = _rig(target_obj, target_map)
        source_pose, source_world, read_from = read_motion(source_obj, source, frames)
        source = _with_world(source, source_world)
        settings = rt.RetargetSettings(fps=scene.render.fps / scene.render.fps_base, exact=bool(exact))
        target_basis = _pose_property(target_obj.pose.bones, "matrix_basis", (4, 4)).transpose(0, 2, 1)
        if len(target.names) != len(target_basis):  # a control rig's skeleton: its bones' own bases
            target_basis = target_basis[[target_obj.pose.bones.find(name) for name in target.names]]
        plan = rt.plan_retarget(source, source_pose, target, target_basis, settings, boxes, ground=ground)
        if floor is not None and plan.ground is not None and plan.ground != float(floor):
            raised = source.matrix_world.copy()  # the plan is the source's, raised onto the floor
            raised[2, 3] += float(floor) - plan.ground
            source = _with_world(source, raised)
            plan = rt.plan_retarget(source, source_pose, target, target_basis, settings, boxes, ground=ground)
    except SolverInputError as ex:
        raise AdjustError(f"Cannot retarget '{source_obj.name}' onto '{target_obj.name}': {ex}") from None
    names = (("ground",) if ground else ()) + tuple(f"object {obj.name}" for obj in objects)
    return Prepared(source, target, plan, frames, read_from, source_pose, target_basis, names)


def write_pose(context, target_obj, target, pose_matrices, frames, action_name):
    """Key every mapped bone of ``target_obj`` (``target`` its Rig) at ``pose_matrices`` (F,J,4,4, armature
    space) over ``frames`` into a new action named ``action_name``, assigned to it: each bone's rotation in
    its rotation mode, and the root's location; on a control rig, the controls that pose the mapped bones.
    Returns (action, keyed bone names)."""
    written = sorted({b for bones in target.groups.values() for b in bones})
    if control_rig.is_generated_rigify(target_obj):
        action = _new_action(target_obj, action_name)  # before posing: the old action no longer drives the controls
        bone_map = mapping.BoneMap({g: [target.names[b] for b in bones] for g, bones in target.groups.items()})
        tolerance = adjustment.settings_of(target_obj).chain.tolerance / float(np.linalg.norm(target.matrix_world[:3, 0]))
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
    modes = tuple(pb.rotation_mode for pb in target_obj.pose.bones)
    channels = _channels(target_obj, target, basis, written, modes)
    action = _new_action(target_obj, action_name)
    keyframes.key_bones_frames(target_obj, None, frames, channels)
    context.scene.frame_set(context.scene.frame_current)  # show the new action's pose
    return action, tuple(channels)


# --- reading --------------------------------------------------------------------------------------------


def read_motion(obj, rig, frames):
    """The armature's pose at ``frames`` (``rig`` = its solver.retarget.Rig): (pose matrices (F,J,4,4) in the
    space of the returned world matrix (4,4), how it was read). From the action's F-Curves when they alone
    move the bones, else frame by frame."""
    if _why_not_fcurves(obj) is None:
        basis = _basis_from_fcurves(obj, frames)
        return rt.forward_kinematics(rig, basis), np.array(obj.matrix_world, dtype=np.float64), "F-Curves"
    snapshot = pose.read_pose_frames(obj, frames)
    world = snapshot.matrix_world
    # One world matrix for all frames: the motion of an animated object goes into the pose matrices.
    relative = np.linalg.inv(world[0])[None] @ world
    return relative[:, None] @ snapshot.pose_matrices, world[0].copy(), "frame by frame"


def _why_not_fcurves(obj):
    """None when the action's F-Curves alone give the pose (the fast path is exact), else why not."""
    anim = obj.animation_data
    if anim is None or anim.action is None:
        return "no action"
    if anim.use_tweak_mode or (anim.use_nla and any(not t.mute and len(t.strips) for t in anim.nla_tracks)):
        return "NLA tracks"
    if len(anim.drivers):
        return "drivers"
    if abs(anim.action_influence - 1.0) > 0.0:
        return "action influence"
    if obj.parent is not None or any(c.enabled for c in obj.constraints):
        return "the object is parented or constrained"
    for fc in keyframes.animating_fcurves(obj):
        if not fc.data_path.startswith("pose.bones["):
            return "the action animates more than bones"
    for pb in obj.pose.bones:
        if any(c.enabled and c.influence > 0.0 for c in pb.constraints):
            return "bone constraints"
    for bone in obj.data.bones:
        if (not bone.use_inherit_rotation or bone.inherit_scale != 'FULL' or not bone.use_local_location
                or bone.use_relative_parent):
            return "bones that do not inherit plainly"
    return None


def _basis_from_fcurves(obj, frames):
    """matrix_basis (F,J,4,4) from the action's F-Curves at ``frames``; unanimated channels keep the pose
    bones' current values."""
    pose_bones = obj.pose.bones
    names = [pb.name for pb in pose_bones]
    index = {n: i for i, n in enumerate(names)}
    modes = [pb.rotation_mode for pb in pose_bones]
    count, frames_n = len(names), len(frames)
    used = {"location", "scale"} | {rt.ROTATION_PROPERTY[m] for m in modes}
    values = {prop: np.broadcast_to(_pose_property(pose_bones, prop, (size,)), (frames_n, count, size)).copy()
              for prop, size in pose.CHANNEL_SIZES.items() if prop in used}
    lookup = {}  # curves keyed on the same frames (a BVH import keys every frame) share one key search
    for fc in keyframes.animating_fcurves(obj):
        match = _BONE_PATH.match(fc.data_path)
        if match is None or fc.mute or (fc.group is not None and fc.group.mute):
            continue
        bone = index.get(match.group(1).replace('\\"', '"').replace("\\\\", "\\"))
        prop = match.group(2)
        if bone is None or prop not in values or not 0 <= fc.array_index < values[prop].shape[2]:
            continue
        if prop.startswith("rotation_") and rt.ROTATION_PROPERTY[modes[bone]] != prop:
            continue  # the bone rotates by another property: this curve has no effect
        values[prop][:, bone, fc.array_index] = _evaluate(fc, frames, lookup)
    if len(set(modes)) == 1:  # one rotation mode throughout (as imports make): no gathering by mode
        rotation = rt.rotation_matrices(modes[0], values[rt.ROTATION_PROPERTY[modes[0]]])
    else:
        rotation = np.empty((frames_n, count, 3, 3))
        for mode in set(modes):
            bones = [i for i, m in enumerate(modes) if m == mode]
            rotation[:, bones] = rt.rotation_matrices(mode, values[rt.ROTATION_PROPERTY[mode]][:, bones])
    return rt.basis_matrices(values["location"], rotation, values["scale"])


def _evaluate(fcurve, frames, lookup):
    """The F-Curve at ``frames``: key values where keys sit on the frames (Blender returns exactly those),
    F-Curve.evaluate elsewhere and whenever modifiers may change the curve. ``lookup`` caches the key search
    by key frames."""
    points = fcurve.keyframe_points
    n = len(points)
    if n == 0 or any(not m.mute for m in fcurve.modifiers):
        return np.array([fcurve.evaluate(float(f)) for f in frames])
    co = np.empty(2 * n, dtype=np.float32)
    points.foreach_get("co", co)
    x = co[0::2]
    key = x.tobytes()
    search = lookup.get(key)
    if search is None:
        order = np.argsort(x, kind="stable") if np.any(np.diff(x) < 0.0) else None
        ordered = (x if order is None else x[order]).astype(np.float64)
        at = np.clip(np.searchsorted(ordered, frames - _SAME_FRAME), 0, n - 1)
        on_key = np.abs(ordered[at] - frames) <= _SAME_FRAME
        between = np.nonzero(~on_key)[0]
        # A key on every frame, in a row (a BVH import keys every frame): the values are one slice.
        run = int(at[0]) if (order is None and between.size == 0 and len(at)
                             and np.array_equal(at, np.arange(at[0], at[0] + len(at)))) else None
        search = lookup[key] = (order, at, on_key, between, run)
    order, at, on_key, between, run = search
    y = co[1::2]
    if run is not None:
        return y[run:run + len(frames)].astype(np.float64)
    y = y.astype(np.float64)
    if order is not None:
        y = y[order]
    out = np.where(on_key, y[at], 0.0)
    for i in between:
        out[i] = fcurve.evaluate(float(frames[i]))
    return out


def _pose_property(collection, prop, shape):
    size = int(np.prod(shape))
    buffer = np.empty(len(collection) * size, dtype=np.float32)
    collection.foreach_get(prop, buffer)
    return buffer.reshape((len(collection),) + shape).astype(np.float64)


def _rig(obj, bone_map):
    """solver.retarget.Rig of an armature object, its groups from ``bone_map``. A control rig's Rig is its
    mapped skeleton alone (control_rig), in the metarig's hierarchy: the controls are posed from it."""
    if control_rig.is_generated_rigify(obj):
        return _skeleton_rig(obj, bone_map)
    bones = obj.data.bones
    names = tuple(b.name for b in bones)
    index = {n: i for i, n in enumerate(names)}
    parents = [index[b.parent.name] if b.parent else -1 for b in bones]
    if any(p >= i for i, p in enumerate(parents)):
        raise AdjustError(f"Armature '{obj.name}': a bone is listed before its parent")
    connected = np.array([b.use_connect for b in bones], dtype=bool)
    groups = {g: tuple(index[b] for b in members) for g, members in bone_map.groups.items()}
    return rt.Rig(names=names, parents=parents,
                  rest=_pose_property(bones, "matrix_local", (4, 4)).transpose(0, 2, 1),
                  lengths=_pose_property(bones, "length", ()), connected=connected, groups=groups,
                  matrix_world=np.array(obj.matrix_world, dtype=np.float64))


def _skeleton_rig(obj, bone_map):
    """The Rig of a control rig's mapped bones, parents first in the metarig's hierarchy."""
    all_names = tuple(b.name for b in obj.data.bones)
    all_parents = control_rig.skeleton_parents(all_names, [all_names.index(b.parent.name) if b.parent else -1
                                                           for b in obj.data.bones])
    mapped = [bone for _group, bone in bone_map.items()]
    depth = {}

    def depth_of(i):
        if i not in depth:
            depth[i] = 0 if all_parents[i] < 0 else depth_of(int(all_parents[i])) + 1
        return depth[i]

    order = sorted((all_names.index(b) for b in mapped), key=depth_of)
    local = {i: k for k, i in enumerate(order)}

    def mapped_parent(i):  # the nearest mapped ancestor in the metarig's hierarchy
        j = int(all_parents[i])
        while j >= 0 and j not in local:
            j = int(all_parents[j])
        return local.get(j, -1)

    bones = [obj.data.bones[all_names[i]] for i in order]
    names = tuple(b.name for b in bones)
    groups = {g: tuple(names.index(b) for b in members) for g, members in bone_map.groups.items()}
    return rt.Rig(names=names, parents=[mapped_parent(i) for i in order],
                  rest=np.array([np.array(b.matrix_local) for b in bones], dtype=np.float64),
                  lengths=np.array([b.length for b in bones], dtype=np.float64),
                  connected=np.array([b.use_connect for b in bones], dtype=bool), groups=groups,
                  matrix_world=np.array(obj.matrix_world, dtype=np.float64))


def _with_world(rig, world):
    return rt.Rig(rig.names, rig.parents, rig.rest, rig.lengths, rig.connected, rig.groups, world)


def _source_map(obj):
    """The source's bone map, without storing anything on it (the source is never changed)."""
    stored = mapping.load_map(obj)
    desc = mapping.describe_armature(obj)
    if stored is not None and not stored.problems(desc):
        return stored
    return mapping.map_rig(desc)


def _check_source(obj):
    if obj is None:
        raise AdjustError("No source armature: select the armature whose motion to retarget")
    if obj.type != 'ARMATURE':
        raise AdjustError(f"Source '{obj.name}' is not an armature")
    if obj.mode == 'EDIT':
        raise AdjustError(f"Source '{obj.name}' is in Edit Mode: leave it to read its motion")
    anim = obj.animation_data
    if anim is None or (anim.action is None and not any(len(t.strips) for t in anim.nla_tracks)):
        raise AdjustError(f"Source '{obj.name}' has no animation to retarget")


def _frames(source_obj, frame_start, frame_end):
    action = source_obj.animation_data.action
    if frame_start is None or frame_end is None:
        if action is None:
            raise AdjustError(f"Source '{source_obj.name}' has no action: give the frame range")
        lo, hi = action.frame_range
        frame_start = int(round(lo)) if frame_start is None else frame_start
        frame_end = int(round(hi)) if frame_end is None else frame_end
    if int(frame_end) < int(frame_start):
        raise AdjustError(f"Frame range {frame_start}..{frame_end} is empty")
    return np.arange(int(frame_start), int(frame_end) + 1, dtype=np.float64)


def _contact_boxes(context, objects):
    """World bounding boxes (mins, maxs) (K,3) of the contact objects, as evaluated."""
    depsgraph = context.evaluated_depsgraph_get()
    mins, maxs = [], []
    for obj in objects:
        evaluated = obj.evaluated_get(depsgraph)
        world = np.array(evaluated.matrix_world, dtype=np.float64)
        corners = np.array([tuple(c) for c in evaluated.bound_box], dtype=np.float64)
        if len(corners) == 0:
            raise AdjustError(f"Contact object '{obj.name}' has no extent")
        points = corners @ world[:3, :3].T + world[:3, 3]
        mins.append(points.min(axis=0))
        maxs.append(points.max(axis=0))
    return np.array(mins), np.array(maxs)


def _frame_number(value):
    return int(value) if float(value).is_integer() else float(value)


def _action_name(obj):
    action = obj.animation_data.action if obj.animation_data else None
    return action.name if action is not None else obj.name


# --- writing --------------------------------------------------------------------------------------------


def _channels(obj, rig, basis, written, modes):
    """{bone: {property: (F,n)}}: each written bone's rotation in its mode, continuous from its current value;
    the root's location too."""
    linear = basis[..., :3, :3]
    squares = linear * linear  # unit columns (scale removed); the sums written out, faster than np.sum here
    rotation = linear / np.sqrt(squares[..., 0:1, :] + squares[..., 1:2, :] + squares[..., 2:3, :])
    out = {rig.names[j]: {} for j in written}
    for mode in sorted({modes[j] for j in written}):  # one conversion per rotation mode
        columns = [k for k, j in enumerate(written) if modes[j] == mode]
        prop = rt.ROTATION_PROPERTY[mode]
        current = _pose_property(obj.pose.bones, prop, (pose.CHANNEL_SIZES[prop],))
        values = rt.rotation_channel(mode, rotation[:, columns], current[[written[k] for k in columns]])
        for c, k in enumerate(columns):
            out[rig.names[written[k]]][prop] = values[:, c]
    root = rig.groups["root"][0]
    out[rig.names[root]]["location"] = basis[:, written.index(root), :3, 3]
    return out


def _new_action(obj, name):
    """A new, empty action named ``name`` (Blender adds .001 if the name is taken) assigned to ``obj``; its
    previous action is kept (keyframes.assign_action)."""
    action = bpy.data.actions.new(name)
    keyframes.assign_action(obj, action)
    return action
