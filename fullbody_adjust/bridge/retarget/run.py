"""Retarget a source armature's motion (e.g. an imported BVH) onto a target armature of other proportions
(paper §6.2.3). The operator and the command line call only ``retarget`` here.

    read   the source's action: its F-Curves read with foreach_get and evaluated at the frames in numpy
           (exactly at keys; F-Curve.evaluate between keys), forward kinematics in numpy. When something
           besides the action moves the bones (NLA, drivers, constraints, an animated or parented object,
           bones that do not inherit plainly) the evaluated pose is read frame by frame instead;
    plan   solver.retarget: rotations through both bone mappings, root and effector trajectories scaled by
           the leg-length ratio and turned to the target's heading, the source's contacts (floor, contact
           objects' boxes, raised supports) found and held, the whole body shifted (smoothly) where a limb
           could not reach its target (solver/retarget/motion.py says exactly how);
    solve  solver.adjust.adjust_frames, one vectorised batch over every frame, in the target's armature space,
           over its mapped bones and their ancestors, with the target's stored solver settings and each elbow
           and knee hinge fixed in its upper bone (solver.retarget.motion_limits: no pops as a limb straightens);
    write  every mapped target bone's rotation (and the root's location), one foreach_set per F-Curve, into a
           NEW action assigned to the target. The source and its action are only read, never changed; the
           target's previous action, if it has no other user, gets a fake user so it is kept.
    measure how the result keeps the source's contacts, on its own bones (solver.retarget.metrics).

Reading is in read, writing in write; this module checks the input, plans, solves and
measures.
"""

from dataclasses import dataclass

import bpy
import numpy as np

from ...solver import SolverInputError
from ...solver.retarget import motion as rt
from ...solver.fullbody.adjust import UNCONSTRAINED
from ...solver.fullbody.adjust import adjust_frames as solve_frames
from ...solver.body.model import LIMB_OF_EFFECTOR
from .. import adjustment, outcome
from ..reading import ik_limits, start_checks
from ..rig import mapping, targets
from ..errors import AdjustError
from .read import check_source, contact_boxes, frame_range, pose_property, read_motion, rig_of, source_map, with_world
from .write import write_pose
from . import partial
from . import root_motion as root_travel
from ...solver.retarget import mirror as mirroring, partial as partial_groups
from ...solver.retarget.root_motion import residual

_REFITS = 2  # solves after the first, at most, with the feet held as the solve shaped them


@dataclass
class RetargetOutcome:
    """What a retarget did, world units. Per frame and effector (solver.retarget.EFFECTORS order):
    targets, residuals (effector -> target distance after the solve), status, contacts (held frames).
    contact_report: how the result keeps the source's contacts, measured on its own bones
    (solver.retarget.metrics.contact_figures: per effector contact error, sliding, frames below the floor,
    pops); contact_error (F,E): the result's contact error on contact frames, NaN elsewhere;
    contact_error_before: the same of the transferred motion before the adjustment."""

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
    units: str = "scene units"  # of every distance here: "m" where the scene's unit system is metres

    def contacts_not_held(self):
        """Frames (summed over effectors) where a contact within reach is not held on the result."""
        return sum(f["not_held_frames"] for f in (self.contact_report or {}).get("effectors", {}).values())

    def warning(self):
        """One line naming what went wrong although the retarget finished (the command line exits 1 for the
        same): a target within reach that was missed (the first effector, its frames and largest residual), or
        a contact within reach that was not held; None when neither happened."""
        missed = ~np.isin(self.status, ("reached", "unreachable", UNCONSTRAINED))
        if missed.any():
            return outcome.missed_target_line(self.effectors, missed, self.residuals, self.status)
        for effector, figures in (self.contact_report or {}).get("effectors", {}).items():
            if figures["not_held_frames"]:
                return f"{effector} does not hold its contact on {figures['not_held_frames']} frames within reach"
        return None

    def summary(self):
        """One line for the operator's report and the command line."""
        met = int(np.sum(self.status == "reached"))
        total = self.status.size
        found = (self.contact_report or {}).get("effectors", {})
        held = ", ".join(f"{e} {int(self.contacts[:, k].sum())}" for k, e in enumerate(self.effectors)
                         if self.contacts[:, k].any())
        line = (f"Retargeted {len(self.frames)} frames into '{self.action.name}' (leg ratio "
                f"{self.leg_ratio:.3g}): {met} of {total} effector targets met, largest residual "
                f"{float(np.max(self.residuals)):.3g} {self.units}; contact frames held: {held or 'none'}")
        if found:
            line += (f"; below the floor on {sum(f['frames_below_floor'] for f in found.values())} frames, "
                     f"{sum(f['pops'] for f in found.values())} pops, "
                     f"{self.contacts_not_held()} contact frames not held")
        return line


def retarget(context, source_obj, target_obj, frame_start=None, frame_end=None, *, contacts=("ground",),
             exact=True, new_action=None, floor=None, progress=None, mirror=False, groups=None, root_motion=None,
             root_bone=None, root_smoothing=None):
    """Retarget ``source_obj``'s motion over [frame_start, frame_end] (default: its action's frame range)
    onto ``target_obj``, into a new action named ``new_action`` (default '<source action>_<target>').

    contacts: what hands and feet may touch, as ``contact_specs`` reads it: 'ground' (planted feet rest on
    the floor, still) and any number of ('object', Object or name) (hands and feet touching the object's box
    are held on it; feet still off the floor stand on something raised). exact: hands on objects at the
    source's own world positions (else scaled like the motion). ``floor``: world height the source's ground is
    moved to (None: where it is). ``mirror``: the source's motion mirrored first, its contact objects' boxes with it
    (solver/retarget/mirror.py).
    ``groups``: only these body groups carried (solver/retarget/partial.py), every other bone keeping the
    target's own F-Curves (bridge/retarget/partial.py). ``root_motion``: where the travel is written, 'hips'
    (None, the default), 'bone' (onto ``root_bone``, created when missing), 'object' or 'in-place'
    (bridge/retarget/root_motion.py; not with ``groups``), its path smoothed over ``root_smoothing`` seconds
    (None: the default, 0: the hips' exactly); the contact figures are those of the world motion the
    root and pose build. Returns a RetargetOutcome; AdjustError (one
    line) on bad input, before anything changes (but the bone map stored on the target, see
    mapping.ensure_map)."""
    progress = progress or (lambda stage, fraction: None)
    progress("reading", 0.0)
    if groups is not None:
        partial.check_partial(target_obj)
        if root_motion not in (None, "hips"):
            raise AdjustError(f"Root motion '{root_motion}' moves every bone, so it cannot go with --groups "
                              f"(a partial retarget keeps the target's own keys elsewhere)")
    prepared = prepare(context, source_obj, target_obj, frame_start, frame_end, contacts=contacts, exact=exact,
                       floor=floor, mirror=mirror)
    target, plan = prepared.target, prepared.plan
    root_request = root_travel.check(target_obj, root_motion, root_bone, target.names[target.groups["root"][0]],
                                     root_smoothing)

    progress("solving", 0.2)
    try:
        model, bones = rt.body_model(target)
        start, heads, tails = plan.start_pose[:, bones], plan.heads[:, bones], plan.tails[:, bones]
        settings = adjustment.settings_of(target_obj)
        hinges = ik_limits.hinge_hints(model, target.rest[bones], start)  # elbows and knees as found at rest
        limits = rt.motion_limits(model, start, heads, tails, settings.human_limits,
                                  bone_x_axes=hinges) if settings.use_limits else None
        limits = ik_limits.joint_limits(target_obj, model, heads, tails, start, settings, defaults=limits,
                                        hinge_axes=hinges)

        def solve():
            return solve_frames(model, heads, tails, plan.targets, rt.EFFECTORS,
                                [targets.DEFAULT_PRIORITY[e] for e in rt.EFFECTORS], settings=settings,
                                limits=limits)

        result = solve()
        # Every bone not solved follows its parent: by its own basis, or (fingers carried over from the
        # source) as in the start pose.
        basis = np.broadcast_to(prepared.target_basis, plan.start_pose.shape).copy()
        basis[:, list(plan.carried)] = rt.basis_from_pose(target, plan.start_pose, list(plan.carried))

        def posed_of(result):
            return rt.carry_unsolved(target, rt.solved_pose(plan, result.rotations, result.heads, bones), bones,
                                     basis)

        # Soles skinned partly to the shins move with the knees as the solve bent them: the feet held again,
        # shaped as solved, and solved again while that moves an ankle target by over 0.1 mm (twice at most).
        for _ in range(_REFITS):
            posed = posed_of(result)
            refitted = plan.refit_feet(posed)
            if np.abs(refitted - plan.world_targets).max() <= 1e-4 * rt.leg_length(target):
                break
            plan.world_targets = refitted
            plan.targets = target.to_armature(refitted)
            result = solve()
    except SolverInputError as ex:
        raise AdjustError(f"Cannot retarget '{source_obj.name}' onto '{target_obj.name}': {ex}") from None

    progress("writing", 0.8)
    name = new_action or f"{_action_name(source_obj)}_{target_obj.name}"
    posed = posed_of(result)
    only = None if groups is None else partial_groups.bones_in_groups(target, groups, range(len(target.names)))
    if only is None:
        action, keyed = root_travel.write(context, root_request, target_obj, target, posed, prepared.frames, name,
                                          plan.carried, plan.ground)
    else:
        own, moving = partial.own_motion(target_obj, target, prepared.frames)  # before it is replaced
        standing = root_travel.standing_basis(target_obj)
        if moving is not None:  # its object's own keys move it: the carried bones keyed to end where solved
            posed = residual(moving, posed)
        action, keyed = write_pose(context, target_obj, target, posed, prepared.frames, name, plan.carried, only)
        root_travel.record_standing(target_obj, action, standing)  # the copy keeps the object's keys
        # contacts measured on the motion written: the groups carried on the target's own
        posed = partial_groups.combined_pose(target, posed, own, only)
        if moving is not None:
            posed = moving[:, None] @ posed
    progress("done", 1.0)

    wrists = np.stack([model.limbs[LIMB_OF_EFFECTOR[e]].end_point(result.heads, result.tails) for e in rt.EFFECTORS],
                      axis=1)  # the hands' and feet's heads; a hand-less arm's last bone's end
    residuals = np.linalg.norm(target.to_world(wrists) - plan.world_targets, axis=-1)
    reachable = {e: result.status[:, k] != "unreachable" for k, e in enumerate(rt.EFFECTORS)}
    # How the result keeps the source's contacts, and how the transferred motion did before the solve.
    fps = context.scene.render.fps / context.scene.render.fps_base
    source_points = _effector_points(prepared.source, prepared.source_pose)
    figures, after = _contact_figures(prepared, _effector_points(target, posed), source_points, reachable, fps)
    _, before = _contact_figures(prepared, _effector_points(target, plan.start_pose), source_points, None, fps)
    return RetargetOutcome(action=action, frames=prepared.frames, effectors=rt.EFFECTORS,
                           targets=plan.world_targets, residuals=residuals, status=result.status,
                           contacts=plan.contacts, leg_ratio=plan.leg_ratio, read_from=prepared.read_from,
                           keyed_bones=keyed, contact_report=_contact_report(prepared, figures, units_of(context)),
                           contact_error=after, contact_error_before=before, units=units_of(context))


def units_of(context):
    """What a world distance is in: "m" in a metric scene of unit scale 1, else "scene units"."""
    settings = context.scene.unit_settings
    return "m" if settings.system == 'METRIC' and abs(settings.scale_length - 1.0) < 1e-9 else "scene units"


def _effector_points(rig, pose):
    """{effector: its points (F,P,3)} of a rig's pose (F,J,4,4), world space."""
    return {e: rt.effector_points(rig, pose, e) for e in rt.EFFECTORS}


def _contact_figures(prepared, target_points, source_points, reachable, fps):
    """rt.contact_figures of the target's effector points against the source's contacts: (figures per
    effector, (F,E) contact error)."""
    plan = prepared.plan
    figures, curves = rt.contact_figures(plan.contact_list, target_points, source_points, plan.boxes, plan.ground,
                                         rt.leg_length(prepared.target), plan.leg_ratio, fps, reachable)
    return figures, np.stack([curves[e] for e in rt.EFFECTORS], axis=1)


def _contact_report(prepared, figures, units="scene units"):
    """The report's contact section: what was asked for, the floor, and per effector its figures with each
    contact by frame number and what it touches."""
    plan = prepared.plan
    objects = [name.split(" ", 1)[1] for name in prepared.contact_names if name.startswith("object ")]
    for e, found in plan.contact_list.items():  # each contact by frame number, and what it touches
        for listed, contact in zip(figures[e]["contacts"], found):
            listed.update(frame_start=_frame_number(prepared.frames[contact.start]),
                          frame_end=_frame_number(prepared.frames[contact.stop - 1]),
                          touches=objects[contact.box] if contact.box >= 0 else contact.kind)
    return {"contacts": list(prepared.contact_names), "floor": plan.ground, "units": units, "effectors": figures}


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
            exact=True, floor=None, mirror=False):
    """Check the input, read the source's motion and plan the retarget (see ``retarget``); changes nothing
    but the target's stored bone map. The target stands where an earlier 'object' root motion's keys found it
    (root_motion.standing_world)."""
    check_source(source_obj)
    start_checks.check_armature(target_obj)
    if target_obj.mode == 'EDIT':
        raise AdjustError(f"'{target_obj.name}' is in Edit Mode: leave it to retarget onto it")
    if source_obj == target_obj:
        raise AdjustError("Source and target are the same armature: pick another source")
    ground, objects = contact_specs(context, contacts)
    boxes = contact_boxes(context, objects) if objects else None
    frames = frame_range(source_obj, frame_start, frame_end)
    anim = target_obj.animation_data
    if anim is not None and anim.use_tweak_mode:
        raise AdjustError(f"'{target_obj.name}' is in NLA tweak mode: leave it to retarget onto it")

    source_bones = source_map(source_obj)
    target_bones = mapping.ensure_map(target_obj)
    scene = context.scene
    try:
        source = rig_of(source_obj, source_bones)
        target = rig_of(target_obj, target_bones)
        # where it stood before an earlier run's root motion keys moved it, if they did
        target = with_world(target, root_travel.standing_world(target_obj))
        source_pose, source_world, read_from = read_motion(source_obj, source, frames)
        source = with_world(source, source_world)
        if mirror:  # the clip mirrored in a mirrored scene: its contact objects go with it
            source_pose = mirroring.mirror_pose(source, source_pose)
            boxes = mirroring.mirror_boxes(source, boxes) if boxes is not None else None
        settings = rt.RetargetSettings(fps=scene.render.fps / scene.render.fps_base, exact=bool(exact))
        target_basis = pose_property(target_obj.pose.bones, "matrix_basis", (4, 4)).transpose(0, 2, 1)
        if len(target.names) != len(target_basis):  # a control rig's skeleton: its bones' own bases
            target_basis = target_basis[[target_obj.pose.bones.find(name) for name in target.names]]
        if floor is not None and ground:  # the source raised so its floor is the one given
            below = rt.source_floor(source, source_pose)
            if below != float(floor):
                raised = source.matrix_world.copy()
                raised[2, 3] += float(floor) - below
                source = with_world(source, raised)
        plan = rt.plan_retarget(source, source_pose, target, target_basis, settings, boxes, ground=ground,
                                floor=float(floor) if floor is not None and ground else None)
    except SolverInputError as ex:
        raise AdjustError(f"Cannot retarget '{source_obj.name}' onto '{target_obj.name}': {ex}") from None
    names = (("ground",) if ground else ()) + tuple(f"object {obj.name}" for obj in objects)
    return Prepared(source, target, plan, frames, read_from, source_pose, target_basis, names)


def _frame_number(value):
    return int(value) if float(value).is_integer() else float(value)


def _action_name(obj):
    action = obj.animation_data.action if obj.animation_data else None
    return action.name if action is not None else obj.name
