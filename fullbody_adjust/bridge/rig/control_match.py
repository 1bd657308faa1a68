"""Posing a control rig through its controls: the controls an animator keys are placed so that the bones they
drive (through constraints, IK and helper bones) reach the solved matrices.

Each control is paired with one bone it drives, in one of two ways:

- rigid: the control's new armature-space matrix is its current one carried by its bone's error,
  ``C <- D @ inv(B) @ C`` (D: the bone's desired matrix, B: its evaluated one); exact in one step when the bone
  follows the control rigidly (FK controls, an IK hand or foot control), a fixed-point step otherwise (a spine
  whose controls pivot in its middle);
- bend: the control sets the bend plane of a two-bone IK chain (its pole, or the chain's base control when the
  rig uses no pole). Turning it about the chain's axis (first bone's head to the end bone's head) turns the IK
  solution about that axis by the same angle, so the step is the angle from the evaluated middle joint to the
  desired one about that axis, and the pair's error is that angle (as an arc at the middle joint). How far the
  middle joint lies from the axis is the chain's stretch, not its bend: a stretchy IK shares its stretch between
  its two bones as its solver finds (on a generated Rigify leg bent 30 degrees, the shin 0.17 % shorter than the
  thigh, the knee 1.4 mm off), which no control sets; counted as the bend's error, it stalled every sweep and
  chose the best one by the knee, not by the hands and feet;
- scale: the control is the first bone of a stretchy IK chain (Rigify's IK shrinks or stretches its bones to
  reach), scaled by the ratio of the chain's desired to its evaluated length (first bone's head, middle joint,
  end bone's head), as Rigify's own IK-to-FK snapping scales it by its first bone's. The chain's length, not
  the first bone's: the IK shares its stretch between the two bones as its solver finds, and matching the first
  bone's length alone left the whole error on the second (a Rigify shin 0.67 % short with the thigh exact).
Pairs are applied level by level, parents' controls first, and the sweep is repeated until every driven bone is within
tolerance or a sweep stops helping; the controls are left as the best sweep placed them. An evaluation of the rig costs
about as much as Blender's own IK on it, so a level is evaluated only when the moves since the last evaluation leave its
pairs' matrices unknown: a rigid pair whose control hangs (in the pose hierarchy) below a control moved since, or below
the bone that control drives, is carried by that move, control and bone alike, and is placed from the carried matrices;
pairs of other limbs are unaffected (limbs are independent given the trunk, which carries them all; a part of the trunk
carries only the limbs its pairs say, ``carries``: a rig's hips control moves its legs, not its arms); the bone of an IK
chain's end control stays with that control when a control it does not hang below moved (a clavicle, the trunk: the
chain still reaches the control; where that does not hold, a chain that cannot reach or a control that follows a moved
one through a constraint, as a Rigify IK parent switch makes it, the sweep's closing evaluation finds the error and the
next sweep corrects it); anything else (a bend or scale pair after a move of its limb, a control not below what moved, a
limb between IK and FK) is evaluated first. Nothing here knows a rig's names: the rig module (``control_rig``) says
which control drives which bone.

Where a prediction is wrong, so that the rig is evaluated more than once: an IK chain whose end or base moved.
Its bend plane and its length after the move are predicted (chain_prediction, whose notes say where that is
wrong), and its bend and scale are stepped from the prediction in the sweep that moves its end. Blender's IK is
iterative: Rigify's stretch (ik_stretch 0.1 on both bones) shares a stretch between the bones as its solver finds.
It starts each evaluation from its base control's channels, which a bend step turns about the chain's axis (a
symmetry of the solve), so the chain's length over its base's scale is a function of the target's distance over
that scale alone (chain_steps.record_stretch), learnt from the evaluations of the current frame's placements and
the updates before it; and so is how far the chain's end stops off its target (0.003 mm at 0.75 of its reach,
0.12 mm straight), by which its end control is moved in the same sweep (_correct_end). Near full reach (a straight
arm beyond reach) the IK bends and stretches its chain from that start, and its length follows the base's scale
less and less: each sweep there costs an evaluation for a smaller gain. A chain that cannot be predicted (beyond
reach, a limb between IK and FK) has its bend and scale stepped from an evaluation that shows its end where it goes;
each further sweep (one evaluation) steps its scale again and corrects its end control by the chain's miss. An FK
rig, and the trunk, clavicles and IK end controls of any rig, are placed from the rest relations and carried
matrices in one go, shown by the sweep's closing evaluation. A caller that has just had the rig evaluated (a click,
a Live update) says so, and the matching does not evaluate it first.
"""

import math
from dataclasses import dataclass

import numpy as np
from mathutils import Matrix

from ...solver.maths.geometry import affine_inverse
from ...solver.vocabulary import ROTATION_PROPERTY
from ..writing.channels import continuous_rotation
from . import chain_prediction, chain_steps
from .chain_steps import head as _head, matrix as _matrix, tail as _tail


# A sweep that leaves the largest error above this fraction of the previous sweep's is the last one.
_STALLED = 0.7


# After a sweep's closing evaluation, an IK chain's end control moved by at most this fraction of its bone's length
# only corrects the chain's miss: its bend and scale are stepped from that evaluation, not from one more.
_CORRECTION = 1e-3

# A bend or scale pair (an IK chain's middle joint: an elbow, a knee, never a target) is met within this many times the
# solve's tolerance: 0.1 mm at the default 1e-5 m, what the deform bones are held to. Its last tenth cost a sweep (an
# evaluation of the rig) on about every update: Rigify's stretchy IK answers a scaling by a share that keeps changing.
_MIDDLE_JOINT = 10.0

# The group of the trunk's pairs that carry the whole body: a move of one carries every limb.
TRUNK_GROUP = "trunk"


@dataclass(frozen=True)
class ControlPair:
    """``control`` drives ``bone``; controls of lower ``level`` are placed first."""

    control: str
    bone: str
    level: int
    end: str = None  # bend and scale pairs: the bone whose head ends the chain (hand, foot)
    kind: str = "rigid"  # 'rigid' | 'bend' | 'scale'
    # The limb (or TRUNK_GROUP) whose bones the pair poses; pairs of different limbs do not affect each other.
    # None: unknown, every move is evaluated before the pair is placed.
    group: str = None
    # A rigid pair whose bone goes where its control goes, whatever else moves (an IK chain's end control: the
    # chain reaches it): a move of a control it does not hang below is taken to leave the control, and so the bone,
    # where they were (module notes: the sweep's closing evaluation catches where that is wrong).
    follows_control: bool = False
    # The groups besides its own whose bones a move of the control moves (a TRUNK_GROUP pair's: every group).
    carries: tuple = ()
    # Bend and scale pairs: the bone whose damped track at the chain's end carries the chain's IK solution (Rigify's
    # IK swing), for chain_prediction; None: the chain is not predicted (a pole sets its bend plane).
    swing: str = None

    @property
    def bends(self):
        return self.kind == "bend"


def _pair_error(pose_bones, pair, desired, lengths):
    chain = chain_steps.chain_of(pose_bones, pair, lengths)
    return _error(_matrix(pose_bones[pair.bone]), pair, chain, desired, lengths)


def match_controls(obj, view_layer, pairs, desired, tolerance, max_sweeps=8, evaluated=False, stretch=None,
                   predict=True):
    """Place the controls of ``pairs`` so each pair's bone reaches ``desired[bone]`` (4x4 armature-space
    matrices). Evaluates the rig (``view_layer.update()``) first unless ``evaluated`` (the caller has just had it
    evaluated and changed nothing since), where the moves since the last evaluation leave a level's matrices
    unknown (module notes), and after each sweep. Returns the largest remaining bone error (armature units) of the
    best sweep, whose channels the controls are left holding. ``stretch``: the IK chains' stretch samples to step
    their scales from and add to ({first bone: samples}; None: none kept). ``predict``: an IK chain whose end or
    base moved is predicted (chain_prediction) rather than evaluated before its bend and scale steps;
    control_frames.control_channels predicts for one pose Blender has just evaluated (Live, a click), not for frames
    in a row (a retarget, Adjust Frames), whose IK ends met then lie within 0.1 mm of the solve on every version
    (measured: with prediction a generated rig's retargeted toe ended 0.111 mm off on bpy 4.5 and 5.2)."""
    pose_bones = obj.pose.bones
    levels = sorted({p.level for p in pairs})
    by_level = [[p for p in pairs if p.level == level] for level in levels]
    lengths = {p.bone: pose_bones[p.bone].bone.length for p in pairs}
    controls = list(dict.fromkeys(p.control for p in pairs))
    above = {c: {b.name for b in pose_bones[c].parent_recursive} for c in controls}
    if not evaluated:
        view_layer.update()
    error = best_error = np.inf
    best = None
    scaled = {}  # scale pairs: (control's Y scale, chain length) at their last step (None: left as they are)
    stretch = {} if stretch is None else stretch
    samples = {p: stretch.setdefault(p.bone, []) for p in pairs if p.kind == "scale"}
    # A scale pair's chain's end control (an IK hand or foot control: the pair its chain's end follows).
    ends = {p: q for p in samples for q in pairs if q.follows_control and q.bone == p.end}
    for sweep in range(max_sweeps):
        pending = []  # (pair, armature-space step) of the controls moved since the last evaluation
        written = {}  # pair: (the carry its control's move was written against or None, the matrix written)
        corrections = set()  # pairs of ``pending`` that only corrected a chain's end (_carried_or_apart)
        for level_pairs in by_level:
            carries = [_carried_or_apart(pair, pending, above, corrections) if pending else None
                       for pair in level_pairs]
            predictions = {}
            if pending and predict:
                carries = [carry if carry is not None or pair.kind == "rigid"
                           else _predicted(pair, pending, above, corrections, pose_bones, lengths, predictions)
                           for pair, carry in zip(level_pairs, carries)]
            if pending and any(carry is None for carry in carries):
                view_layer.update()
                pending = []
                corrections.clear()
                predictions.clear()
                carries = [None] * len(level_pairs)
            moves, scales, chains = [], [], {}
            for pair, carry in zip(level_pairs, carries):
                bone = _matrix(pose_bones[pair.bone])
                if carry is not None:
                    bone = carry @ bone
                chain = chain_steps.chain_of(pose_bones, pair, lengths, predictions.get(pair),
                                             stretch.get(pair.bone, ()))
                chains[pair] = chain
                if pair in samples and pair not in predictions:
                    chain_steps.record(pose_bones, pair, chain, lengths, samples[pair], ends.get(pair))
                if _error(bone, pair, chain, desired, lengths) <= _tolerance(pair, tolerance):
                    continue
                control = pose_bones[pair.control]
                if pair.kind == "scale":
                    scale = chain_steps.scale_step(pair, control, chain, desired, lengths, scaled, pair in predictions,
                                                   samples[pair])
                    if scale is not None:
                        scales.append((control, scale))
                    continue
                if pair.bends:
                    step = chain_steps.bend_step(chain, pair, desired, lengths)
                    if step is None:
                        continue
                else:
                    step = desired[pair.bone] @ affine_inverse(bone)
                # An IK base control (a swing's chain) is turned from where its channels put it, not from where its
                # IK left it: the IK then starts every evaluation from the same pose turned about the chain's axis,
                # a symmetry of its solve, and its stretch stays a function of the target's distance alone
                # (chain_steps.record_stretch); turned from the IK's result, each solve started from the last one's.
                placed = chain_steps.unconstrained(control) if pair.swing else _matrix(control)
                if carry is None:
                    moves.append((pair, control, step, step @ placed))
                else:
                    # Blender turns an armature-space matrix into channels against the parent's evaluated
                    # matrix, which the carry has not reached yet: hand it the matrix relative to that.
                    new = step @ carry @ placed
                    moves.append((pair, control, step @ carry, affine_inverse(carry) @ new))
            if not moves and not scales and not predictions:
                continue
            for pair, control, step, new in moves:
                written[pair] = (carries[level_pairs.index(pair)], new)
                # A bend step only turns its control, but Blender re-derives every channel from the matrix
                # written, which lost an IK base's scale (a stretchy chain's length): that is kept as it was.
                kept = tuple(control.scale) if pair.bends else None
                control.matrix = Matrix(new.tolist())
                if kept is not None:
                    control.scale = kept
                pending.append((pair, step))
                if sweep and pair.follows_control and \
                        _moved_by(step, pose_bones[pair.bone]) <= _CORRECTION * lengths[pair.bone]:
                    corrections.add(pair)
            for control, scale in scales:
                control.scale = scale.tolist()
            for pair in predictions:
                if pair in ends and pair in samples:
                    _correct_end(pair, ends[pair], chains[pair], pose_bones, lengths, samples[pair], pending, written,
                                 above)
            if scales:
                view_layer.update()
                pending = []
                corrections.clear()
        if pending:
            view_layer.update()
        errors = [_pair_error(pose_bones, p, desired, lengths) for p in pairs]
        for pair in samples:
            chain_steps.record(pose_bones, pair, chain_steps.chain_of(pose_bones, pair, lengths), lengths,
                               samples[pair], ends.get(pair))
        previous, error = error, max(errors)
        if error < best_error:
            best_error, best = error, read_channels(obj, controls)
        met = all(e <= _tolerance(p, tolerance) for p, e in zip(pairs, errors))
        if met or error > _STALLED * previous:
            break  # met, or a sweep no longer helps (an IK chain's own solver tolerance, a stretchy chain)
    if error > best_error:
        # A sweep can still land farther off than one before it (a stretchy chain near its IK's precision):
        # the controls go back to the best one.
        _set_channels(obj, best)
    return best_error


def _set_channels(obj, channels):
    """Put back channels as read_channels read them (RNA sets: Blender evaluates the rig again)."""
    for name, props in channels.items():
        pose_bone = obj.pose.bones[name]
        for prop, value in props.items():
            setattr(pose_bone, prop, value.tolist())


def _correct_end(pair, end, chain, pose_bones, lengths, samples, pending, written, above):
    """Move the end control ``end`` of the predicted chain ``chain`` of scale pair ``pair`` by the change of its
    IK's miss (chain_prediction.end_correction) at the chain's new stretch, so that the chain's end, not the control,
    lands where the control's step put the end (or where it was, the control unmoved and below no moved control:
    the trunk carried the chain's base); its step in ``pending`` takes the move (``written[end]``: the carry its
    control's matrix was written against, or None, and that matrix)."""
    control = pose_bones[end.control]
    k = next((i for i, (moved, _step) in enumerate(pending) if moved == end), None)
    if k is None and any({moved.control, moved.bone} & above[end.control] for moved, _step in pending):
        return
    carry, new = written[end] if k is not None else (None, _matrix(control))
    delta = chain_prediction.end_correction(chain, np.eye(4) if k is None else pending[k][1],
                                            _matrix(control)[:3, 3], _matrix(pose_bones[end.bone])[:3, 3], samples,
                                            pose_bones[pair.control].scale[1], lengths[pair.bone])
    if delta is None:
        return
    move = np.eye(4)
    move[:3, 3] = delta
    if k is None:
        pending.append((end, move))
    else:
        pending[k] = (end, move @ pending[k][1])
    relative = move if carry is None else affine_inverse(carry) @ move @ carry
    written[end] = (carry, relative @ new)
    control.matrix = Matrix((relative @ new).tolist())


def _tolerance(pair, tolerance):
    """The error ``pair`` is placed to: ``tolerance`` (the solve's: a hand or a foot is a target) but for a bend or
    scale pair, which sets where an IK chain's middle joint lies and no target, _MIDDLE_JOINT times it."""
    return tolerance if pair.kind == "rigid" else _MIDDLE_JOINT * tolerance


def _carried_or_apart(pair, pending, above, corrections=()):
    """How the moves ``pending`` (pair, step) since the last evaluation move ``pair``'s control and bone: the
    armature-space motion of the nearest moved control above it (the last one: levels are placed parents
    first, and a recorded step is the control's whole motion since the evaluation), the identity when only
    other limbs (or parts of the trunk that do not carry its group) moved, or None when a move may move it in a
    way not known without evaluating the rig (a move of its own limb, or of what carries it, by a control it
    does not hang below). ``corrections``: moves of ``pending`` that only corrected an IK chain's end control by
    the chain's miss (_CORRECTION): that chain's bend and scale pairs are stepped from the last evaluation."""
    carry = np.eye(4)
    for moved, step in pending:
        groups = (moved.group, pair.group)
        if None not in groups and moved.group not in (pair.group, TRUNK_GROUP) and pair.group not in moved.carries:
            continue  # another limb, or a part of the trunk that does not carry this one
        if pair.kind != "rigid" and moved in corrections and moved.group == pair.group:
            continue
        if None in groups or pair.kind != "rigid":
            return None
        if not {moved.control, moved.bone} & above[pair.control]:
            if pair.follows_control:
                continue  # its control stays, and its bone with it
            return None
        carry = step
    return carry


def _predicted(pair, pending, above, corrections, pose_bones, lengths, predictions):
    """The carry of a bend or scale pair's control after the moves ``pending`` when its chain can be predicted
    (chain_prediction: the moves of its limb are its end control's and those of what its base hangs below), the
    prediction kept in ``predictions``; else None (the rig is evaluated first)."""
    carry, end_step = np.eye(4), None
    for moved, step in pending:
        groups = (moved.group, pair.group)
        if None in groups:
            return None
        if moved.group not in (pair.group, TRUNK_GROUP) and pair.group not in moved.carries:
            continue
        if moved.group == pair.group and moved.follows_control and moved.bone == pair.end:
            end_step = step  # its whole motion since the evaluation
        elif {moved.control, moved.bone} & above[pair.control]:
            carry = step
        elif moved not in corrections or moved.group != pair.group:
            return None
    if end_step is None:  # its end control stays, and the chain's end with it (a limb in IK: follows_control)
        end_step = np.eye(4)
    swing = pose_bones.get(pair.swing) if pair.swing else None
    if swing is None:
        return None
    swing = (_matrix(swing), chain_steps.unconstrained(swing))
    end = _matrix(pose_bones[pair.end])[:3, 3]
    chain = chain_prediction.predicted_chain(_matrix(pose_bones[pair.bone]), end,
                                             carry, end_step, swing)
    if chain is None:
        return None
    predictions[pair] = chain
    return chain[0]


def _moved_by(step, pose_bone):
    """How far the armature-space motion ``step`` (4x4) moves ``pose_bone``'s evaluated head."""
    head = _matrix(pose_bone)[:3, 3]
    return float(np.linalg.norm(step[:3, :3] @ head + step[:3, 3] - head))


def _error(bone, pair, chain, desired, lengths):
    """_pair_error from the bone's (possibly carried) matrix ``bone``; a bend or scale pair's from ``chain``
    (chain_steps.chain_of: evaluated or predicted, never carried). A rigid pair's: the larger of its head's and
    its tail's distances."""
    if pair.kind != "rigid":
        return chain_steps.chain_error(chain, pair, desired, lengths)
    b, d, length = bone.tolist(), desired[pair.bone].tolist(), lengths[pair.bone]
    return max(math.dist(_head(b), _head(d)), math.dist(_tail(b, length), _tail(d, length)))


def read_channels(obj, controls, previous=None):
    """{control: {property: (k,) values}}: the location and the rotation (in each control's rotation mode) the
    controls hold now, the rotation made continuous with ``previous`` (same layout) or the control's own value."""
    out = {}
    for name in controls:
        pose_bone = obj.pose.bones[name]
        prop = ROTATION_PROPERTY[pose_bone.rotation_mode]
        value = np.array(getattr(pose_bone, prop), dtype=np.float64)
        if previous is not None and name in previous:
            value = continuous_rotation(prop, pose_bone.rotation_mode, value, previous[name][prop])
        out[name] = {"location": np.array(pose_bone.location, dtype=np.float64), prop: value,
                     "scale": np.array(pose_bone.scale, dtype=np.float64)}
    return out
