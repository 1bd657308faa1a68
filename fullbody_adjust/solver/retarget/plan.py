"""Planning a retarget: the start pose and the effector targets of every frame (see solver/retarget/motion.py,
step 2)."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..fullbody.adjust import sub_base_point
from .contacts import GROUND, RAISED, RetargetSettings, detect_contacts, hold
from ..errors import SolverInputError
from .foot_pivots import ankle_held, drifting_pieces, pivot_bone, pivot_held, roll
from ..maths.geometry import all_set, norm
from ..body.joint_ends import end_points
from .feet import (UNSEEN_FOOT, limit_toe_roll, lowered_within_reach, raised_offsets, refit_step, resting_frames,
                   resting_offsets)
from .rig import (EFFECTOR_CHAIN, EFFECTORS, FEET, Rig, ankle_above_sole, chain_joints, effector_joint,
                  effector_points, facing_turn, hip_centres, leg_length, rest_points, sole_heights)
from .rise import airborne_raise, fold_room, folded, let_go
from .transfer import carried_bones, transfer_pose, translate_body


# A foot planted on more than this fraction of the frames stands on the floor by its holds.
_HELD_STANCE = 0.1
# How far (target leg lengths) a foot standing in place is moved on its own, apart from the other: a rig's or a
# capture's asymmetry (a few centimetres); more is the pose's (a foot raised or pitched), which the legs keep.
_OWN_FOOT = 0.05
# Something raised (inferred from the source alone) whose world height lies more than this (target leg lengths)
# from its height scaled with the motion is out of the target's scale: it is scaled (_at_world_height).
_OUT_OF_SCALE = 0.5
# How far (target leg lengths) a foot's held path may part from its free trajectory over one contact before it is
# held in pieces (foot_pivots.drifting_pieces).
_DRIFT = 0.5


def moving_average(values, half_width):
    """Mean over ±half_width frames (the ends repeated) of values (F,…)."""
    values = np.asarray(values, dtype=np.float64)
    if half_width <= 0 or len(values) < 2:
        return values.copy()
    w = int(half_width)
    padded = np.concatenate([np.repeat(values[:1], w, axis=0), values, np.repeat(values[-1:], w, axis=0)])
    total = np.cumsum(np.concatenate([np.zeros((1,) + values.shape[1:]), padded]), axis=0)
    return (total[2 * w + 1:] - total[:-2 * w - 1]) / (2 * w + 1)


def body_shift(bases, targets, reach, priorities, margin, settle_margin, half_width, max_step=None, preferred=None,
               riding=None):
    """World shifts (F,3) of the whole body that bring each target (F,E,3) within its limb's ``reach`` (E,)
    less ``margin`` from the limb's base (F,E,3) (a knee or elbow stretched straighter swings about a barely
    bent hinge, and a target just within reach or just beyond it moves the trunk or not). On each frame the
    shift nearest ``preferred`` (F,3; None: no shift) that does so (nearest point of the intersection of
    the reach balls, the paper's two-sphere construction; where they do not meet, the higher ``priorities``
    first), smoothed over ±half_width frames, then the smallest further shift that puts every target within
    its reach less ``settle_margin`` again. Continuous from frame to frame, as the nearest point of a convex
    set is; where it still changes by more than ``max_step`` from one frame to the next (the
    reach balls barely meet, or the shift must follow a target that moves fast), smoothed again over windows
    twice as wide each time (the solve reaches what that leaves just out of reach). ``riding`` (F,E) bool: targets
    that move with the body (free trajectories), which no shift brings nearer or farther: they bound nothing
    (None: every target is fixed in the world)."""
    centres = targets - bases  # a shift d serves target k when |centres_k - d| <= radius_k
    frames = len(targets)
    active = np.ones(centres.shape[:2], dtype=bool) if riding is None else ~np.asarray(riding, dtype=bool)
    wanted = np.zeros((frames, 3)) if preferred is None else np.asarray(preferred, dtype=np.float64)
    reach = np.asarray(reach, dtype=np.float64)

    def nearest(start, fraction):
        radii = np.broadcast_to((1.0 - fraction) * reach, active.shape)
        point, _ = sub_base_point(start, centres, radii, active, priorities, "priority")
        return point

    first = nearest(wanted, margin)
    shift = nearest(moving_average(first, half_width), settle_margin)
    width = max(int(half_width), 1)
    while max_step is not None and width <= frames and _largest_step(shift) > max_step:
        shift = moving_average(shift, width)
        width *= 2
    return shift


def _largest_step(points):
    return float(norm(np.diff(points, axis=0)).max()) if len(points) > 1 else 0.0


@dataclass
class RetargetPlan:
    """What the solve needs and what the caller reports, for F frames.

    start_pose (F,Jt,4,4): the transferred pose (target armature space); heads/tails (F,Jt,3) of it in
    armature space (tails: the joint ends, joint_ends.end_points, never the importer's tails); targets (F,4,3) for
    EFFECTORS in armature space, world_targets the same in world space;
    contacts (F,4) bool: frames held at a contact; contact_list {effector: [Contact]} the source's contacts, a
    foot's surface the height it is held at (contact_intervals the same as (start, stop) pairs); leg_ratio
    target/source; ground: world z of the floor (the source's soles, Rig.soles), None when the floor is not a
    contact; boxes: the contact objects' world boxes (mins, maxs) or None; refit_feet(pose) the world targets
    with the feet held as shaped in another pose (the solved one); carried: target bones outside the bone map that take the source's motion
    (fingers both rigs have: fingers), their start pose to be kept relative to their parents."""

    start_pose: np.ndarray
    heads: np.ndarray
    tails: np.ndarray
    targets: np.ndarray
    world_targets: np.ndarray
    contacts: np.ndarray
    contact_intervals: dict
    leg_ratio: float
    ground: float
    contact_list: dict = None
    boxes: tuple = None
    effectors: tuple = EFFECTORS
    refit_feet: object = None
    carried: tuple = ()


def plan_retarget(source, source_pose, target, target_basis, settings=RetargetSettings(), boxes=None, ground=True,
                  floor=None):
    """The start pose and effector targets that carry ``source_pose`` (F,Js,4,4, source armature space)
    over to ``target`` (its unmapped bones at ``target_basis`` (Jt,4,4)). ``boxes``: (mins, maxs) (K,3)
    each, world boxes of contact objects (None: none); ``ground``: the floor is a contact; ``floor``: its
    world height (None: ``source_floor``). See the module docstring of solver/retarget/motion.py."""
    if not isinstance(source, Rig) or not isinstance(target, Rig):
        raise SolverInputError("source and target must be Rigs")
    source_pose = np.asarray(source_pose, dtype=np.float64)
    if source_pose.ndim != 4 or source_pose.shape[1:] != (len(source), 4, 4) or len(source_pose) == 0:
        raise SolverInputError(f"source pose must have shape (F,{len(source)},4,4), got {source_pose.shape}")
    if not all_set(np.isfinite(source_pose)):
        raise SolverInputError("source pose has NaN/inf")
    target_basis = np.asarray(target_basis, dtype=np.float64)
    if target_basis.shape != (len(target), 4, 4):
        raise SolverInputError(f"target basis must have shape ({len(target)},4,4), got {target_basis.shape}")
    if boxes is not None:
        boxes = tuple(np.asarray(b, dtype=np.float64).reshape(-1, 3) for b in boxes)
    leg_s, leg_t = leg_length(source), leg_length(target)
    if not (leg_s > 0.0 and leg_t > 0.0):
        raise SolverInputError("a rig's legs have zero length")
    ratio = leg_t / leg_s

    # The motion turned to the target's heading (about the world origin; Z, so heights, unchanged): by the
    # angle between the skeletons' rest facings (from hips and feet, whatever the objects' axes), so the
    # target faces its travel as the source faces its own.
    heading = facing_turn(source, target)
    turn = np.eye(4)
    turn[:3, :3] = heading
    turned = replace(source, matrix_world=turn @ source.matrix_world)
    s_heads = source.world_points(source_pose)[0]
    floor = source_floor(source, source_pose) if floor is None else float(floor)
    # Scale about the floor below each rig's rest hips: the source's motion, re-anchored on the target.
    anchor_s = hip_centres(turned, rest_points(turned)[0])
    anchor_t = hip_centres(target, rest_points(target)[0])
    anchor_s[2] = anchor_t[2] = floor

    def scaled(points):
        return anchor_t + ratio * (points @ heading.T - anchor_s)

    start = transfer_pose(turned, source_pose, target, target_basis, scaled(hip_centres(source, s_heads)))
    s_points = {e: effector_points(source, source_pose, e) for e in EFFECTORS}  # where the source touches things
    soles = ankle_above_sole(target, start)  # the transferred feet's own ankle heights above their soles
    if ground:  # the body at the height where the feet stand on the floor as the source's do
        ankles = np.stack([target.to_world(start[:, target.groups[e][0], :3, 3])[:, 2] for e in FEET], axis=1)
        offsets = resting_offsets(ankles, s_points, soles, floor, leg_s, settings) \
            or raised_offsets(ankles, s_points, soles, floor, ratio)
        if offsets:
            translate_body(target, start, np.broadcast_to([0.0, 0.0, np.mean(list(offsets.values()))],
                                                          (len(start), 3)))
    t_heads, t_ends = target.world_points(start)
    frames = len(source_pose)
    blend = settings.frames(settings.blend_duration) if settings.blend_duration else 0
    contacts = np.zeros((frames, len(EFFECTORS)), dtype=bool)
    found = {e: detect_contacts(e, s_points[e], floor if ground else None, boxes, leg_s, settings) for e in EFFECTORS}
    raised_scaled = any(_out_of_scale(c, floor, ratio, leg_t) for cs in found.values() for c in cs)
    for k, e in enumerate(EFFECTORS):
        found[e] = [c if not np.isfinite(c.surface) or _at_world_height(c, settings, raised_scaled) else
                    replace(c, surface=floor + ratio * (c.surface - floor))  # the height its foot is held at
                    for c in found[e]]
        for c in found[e]:
            contacts[c.start:c.stop, k] = True
    step = settings.blend_speed * leg_t / settings.fps
    # The joint each foot stands on (ball, or ankle), and the frames the source holds it still near the floor.
    rule = settings.detection
    pivots = {e: pivot_bone(source, target, e) for e in FEET}
    pinned = {e: pivot_held(s_heads[:, pivots[e][0]], s_heads[:, source.groups[e][0]], settings.fps,
                            rule.plant_speed * leg_s, rule.plant_height * leg_s) for e in FEET}
    ankles_pinned = {e: ankle_held(s_heads[:, source.groups[e][0]], pinned[e], settings.fps, rule.plant_speed * leg_s,
                                   rule.plant_height * leg_s, settings.frames(rule.raised_min_duration)) for e in FEET}

    # Free of contacts, each wrist and ankle goes where the transferred pose puts it (its limb keeps the
    # source's angles); the holds are blended into that.
    free = np.stack([effector_joint(target, t_heads, t_ends, e) for e in EFFECTORS], axis=1)
    own = free.copy()  # where the transferred limbs put each wrist and ankle: within reach, moving with the body
    if ground:
        legs = [EFFECTOR_CHAIN[e] for e in FEET]
        _stand_in_place(free, found, s_points, soles, floor, leg_s, settings, _OWN_FOOT * leg_t,
                        np.stack([target.to_world(start[:, target.groups[g][-2], :3, 3]) for g in legs], axis=1),
                        [(1.0 - settings.reach_margin) * limb_reach(target, g) for g in legs])
        for k, e in ((EFFECTORS.index(e), e) for e in FEET):  # a hold drifting off the free trajectory: in pieces
            found[e] = [replace(c, start=c.start + a, stop=c.start + b) for c in found[e] for a, b in drifting_pieces(
                _foot_path(c, free[c.start:c.stop, k], effector_points(target, start[c.start:c.stop], e), 0.0,
                           target.to_world(start[c.start:c.stop, pivots[e][1], :3, 3]), pinned[e][c.start:c.stop],
                           ankles_pinned[e][c.start:c.stop])[:, :2], free[c.start:c.stop, k],
                (pinned[e] | ankles_pinned[e])[c.start:c.stop], _DRIFT * leg_t)]
            contacts[:, k] = False
            for c in found[e]:
                contacts[c.start:c.stop, k] = True
        # Each foot rolls onto its toes no further than lifts its ankle as the source's does, nor than takes its
        # sole below the floor where it is not held (feet): the leg, not the floor, moves the ankle.
        feet = [EFFECTORS.index(e) for e in FEET]
        limit_toe_roll(source, source_pose, target, start, ratio,
                       np.where(contacts[:, feet], np.inf, free[:, feet, 2] - floor))
        soles = ankle_above_sole(target, start)

    def held(paths, feet=start, soles=soles):
        """Targets (F,E,3): free trajectories ``paths`` (F,E,3) with the holds blended in; feet never below
        the floor. A foot's hold is centred on its free trajectory, the foot shaped as in ``feet`` (F,J,4,4),
        its ankle ``soles`` (F,2) above its sole; a hand's is where the source's is."""
        out = np.empty_like(paths)
        for k, e in enumerate(EFFECTORS):
            holds = []
            for c in found[e]:
                a, b = c.start, c.stop
                if e in FEET:
                    foot = effector_points(target, feet[a:b], e)
                    pivot = target.to_world(feet[a:b, pivots[e][1], :3, 3])
                    path = _foot_path(c, paths[a:b, k], foot, soles[a:b, FEET.index(e)], pivot, pinned[e][a:b],
                                      ankles_pinned[e][a:b])
                else:  # a hand on an object: still, where the source's is (or its scaled place)
                    path = (s_points[e][a:b, 0] if settings.exact else scaled(s_points[e][a:b, 0])).mean(axis=0)
                holds.append((a, b, path, _blend_frames(path, paths[:, k], a, b, blend, step)))
            out[:, k] = hold(paths[:, k], holds, blend)
            if e in FEET and ground:  # never below the floor: the lowest point of the foot at least on it
                lift = np.maximum(floor + soles[:, FEET.index(e)] - out[:, k, 2], 0.0)
                out[:, k, 2] += np.where(contacts[:, k], lift, let_go(lift, step))  # a planted foot stays down
        return out

    # Every target within its limb's reach (see reach_margin): shift the whole body, smoothly, where needed;
    # the free trajectories move with it, and the feet's holds (centred on them); hands stay on their objects.
    bases, reach, inner = [], [], []
    rest_heads, rest_tails = rest_points(target)
    for e in EFFECTORS:
        chain = EFFECTOR_CHAIN[e]
        bases.append(target.to_world(start[:, target.groups[chain][-2], :3, 3]))  # shoulder, hip joint
        last_two = norm(np.diff(chain_joints(target, chain, rest_heads, rest_tails)[-3:], axis=0))
        reach.append(float(last_two.sum()))  # upper arm + forearm, thigh + shin (limb_reach)
        inner.append(folded(*last_two))  # nearer than this, a leg cannot fold
    bases = np.stack(bases, axis=1)
    feet_first = [2.0 if e.startswith("hand") else 3.0 for e in EFFECTORS]
    # The body first moves as its held hands and feet moved. The free trajectories ride on the shift and the
    # holds blend in on top of it, so the shift changes by at most half the blend speed a frame: together
    # they stay within what metrics counts as a pop (POP_SPEED).
    if ground:
        rise = airborne_raise(free, soles, floor, contacts, step)
        lifted = np.zeros((len(rise), 3))
        lifted[:, 2] = rise
        translate_body(target, start, lifted)
        free += lifted[:, None]
        own += lifted[:, None]
        bases += lifted[:, None]
    targets = held(free)
    riding = np.all(targets == own, axis=-1)  # the limb's own: it rides on the shift
    shift = body_shift(bases, targets, reach, feet_first, settings.reach_margin, settings.settle_margin, blend,
                       max_step=0.5 * step, preferred=_held_offset(targets, free, contacts, blend), riding=riding)
    world_targets = held(free + shift[:, None])
    if ground:  # a held foot nearer its hip than the leg folds: the body rises (rise.fold_room)
        shift = fold_room(held, free, bases, shift, ~riding, np.add(inner, settings.reach_margin * np.asarray(reach)),
                           0.5 * step)
        world_targets = held(free + shift[:, None])
    translate_body(target, start, shift)
    heads = start[..., :3, 3]
    tails = end_points(start, target.ends)

    asked = [world_targets, None]  # the targets the pose to refit was solved for, and how far the last refit moved them

    def refit_feet(pose):
        """World targets (F,E,3) again, each held foot shaped as in ``pose`` (F,Jt,4,4: the solved pose, every
        bone as Blender poses it), so that its sole, skinned partly to the shin as a mesh's heel often is,
        rests and rolls on the floor as the knee is finally bent. ``pose`` is the one solved for the targets this
        returned last (the plan's world_targets the first time): from the second call on, each coordinate moves
        to where the last two refits say the targets and the feet they shape agree (feet.refit_step)."""
        wanted = held(free + shift[:, None], pose, ankle_above_sole(target, pose))
        moved = wanted - asked[0]
        out = asked[0] + (moved if asked[1] is None else refit_step(moved, asked[1], 1e-6 * leg_t))
        asked[:] = [out, moved]
        return out

    return RetargetPlan(start_pose=start, heads=heads, tails=tails, targets=target.to_armature(world_targets),
                        world_targets=world_targets, contacts=contacts,
                        contact_intervals={e: [(c.start, c.stop) for c in found[e]] for e in EFFECTORS},
                        leg_ratio=ratio, ground=floor if ground else None, contact_list=found, boxes=boxes,
                        refit_feet=refit_feet, carried=carried_bones(turned, target))


def source_floor(source, pose):
    """World z of the floor under the source's motion (armature-space pose matrices (F,J,4,4)): its soles'
    lowest points, the 2nd percentile over frames (a stumble below the floor is not the floor). A source
    without a mesh has only its joints for soles, and a game character's toe and ankle joints lie inside a
    foot we do not see: where they rest a little above the world's ground plane (above z = 0 by less than
    ``UNSEEN_FOOT`` of a leg) the character was made standing on it, and that plane is the floor."""
    lowest = float(np.percentile(sole_heights(source, pose), 2))
    if not source.skinned_soles and 0.0 < lowest <= UNSEEN_FOOT * leg_length(source):
        return 0.0
    return lowest


def _at_world_height(contact, settings, raised_scaled):
    """Whether a foot's contact rests at its surface's world height (else at that height scaled about the floor
    by the legs' ratio): the floor always; a contact object's box and something raised with ``exact``. But
    something raised is only inferred from the source (a foot still above the floor, no object given): where one
    of the clip's raised supports is out of the target's scale (``raised_scaled``: _out_of_scale), they all
    belong to the source's scale, not to the target's world, and are scaled with the rest of the motion, as one
    structure (Godot's robot, its legs 0.75 of the CMU performer's: the climb's bar at 1.22 m kept and the one at
    1.37 m scaled to 1.02 m put its left foot's bar above its right's, where the source's is below, out of reach)."""
    if contact.kind == GROUND:
        return True
    if not settings.exact:
        return False
    return contact.kind != RAISED or not raised_scaled


def _out_of_scale(contact, floor, ratio, leg):
    """Whether a raised contact's world height and its height scaled about the floor by the legs' ``ratio`` lie
    more than _OUT_OF_SCALE of a leg apart (``leg``: the target's leg length): a bar the source climbs onto at
    1.4 m, out of reach of a character half its size, whose legs would stretch and flip to stand there. A rung a
    step higher or lower for a target 1.2 times the source's size is not."""
    if contact.kind != RAISED:
        return False
    scaled = floor + ratio * (contact.surface - floor)
    return abs(scaled - contact.surface) > _OUT_OF_SCALE * leg


def _foot_path(contact, free, target_points, soles, pivot, pinned, ankle_pinned=None):
    """The ankle's path (n,3) over a foot contact: the target's own foot (points (n,P,3), ankle first, then its
    sole, as transferred) rolls and turns as transferred, from each frame to the next about the joint it stands
    on (``pivot`` (n,3), the target's ball or ankle, on the frames ``pinned`` (n,) where the source holds that
    joint still), else about its ankle on the frames ``ankle_pinned`` (n,) where the source holds its ankle still,
    or else about whichever point of its sole is lowest (heel, ball, toes: the one on the ground):
    foot_pivots.roll. The point it turns about does not slide; the path is centred on ``free`` (n,3), the
    ankle's free trajectory. The lowest point of the sole on the contact's surface (plan_retarget has set it to
    the height the foot is held at: _at_world_height)."""
    size = float(np.ptp(target_points[0], axis=0).max()) if len(target_points) else 0.0
    travel = roll(target_points[:, 0], target_points[:, 1:], pivot, pinned, 1e-9 * max(size, 1e-300), ankle_pinned)
    path = np.empty_like(free)
    path[:, :2] = travel + (free[:, :2] - travel).mean(axis=0)
    path[:, 2] = contact.surface + soles
    return path


def _stand_in_place(free, found, s_points, soles, floor, leg, settings, spread, hips=None, longest=np.inf):
    """Feet the source hardly ever holds still on the floor (planted on at most _HELD_STANCE of the frames: an
    in-place clip, whose stance slides under the body) but that come down to it: their free trajectories in
    ``free`` (F,E,3, changed in place) raised or lowered as a whole, so that their soles are on the floor on the
    frames the source's are lowest (feet.resting_offsets), each by its own height within ``spread`` (world) of
    their mean: whatever each rig's ankle height and sole, the stance stands on the floor, one height per foot
    adds no jerk, and the legs keep the source's angles to each other where the feet differ by more than a rig's
    asymmetry (a dodge whose feet pitch differently, each sole put on the floor on its own, turned Godot's robot's
    thighs 7 degrees off the source's). ``soles`` (F,2): the target's ankles above their soles; ``hips`` (F,2,3): the
    hip joints; off the frames the source's sole is lowest, a foot is lowered no farther from its hip than
    ``longest`` (2,) or its own leg puts it (feet.lowered_within_reach; None: no bound)."""
    ankles = free[:, [EFFECTORS.index(e) for e in FEET], 2]
    offsets = {i: offset for i, offset in resting_offsets(ankles, s_points, soles, floor, leg, settings).items()
               if sum(c.stop - c.start for c in found[FEET[i]] if c.kind == GROUND) <= _HELD_STANCE * len(free)}
    mean = np.mean(list(offsets.values())) if offsets else 0.0
    resting = resting_frames(s_points) if offsets and hips is not None else None
    for i, offset in offsets.items():  # (feet whose stances are held on the floor stand on it by their holds)
        k, by = EFFECTORS.index(FEET[i]), mean + np.clip(offset - mean, -spread, spread)
        free[:, k, 2] += by if hips is None else np.where(  # on the floor where the source's sole is lowest
            resting[:, i], by, lowered_within_reach(free[:, k], hips[:, i], by, longest[i]))


def limb_reach(rig, chain):
    """Upper arm + forearm, thigh + shin of a limb ``chain`` (a group name) at rest: its reach from its base."""
    return float(norm(np.diff(chain_joints(rig, chain, *rest_points(rig))[-3:], axis=0)).sum())


def _held_offset(targets, free, contacts, half_width):
    """(F,3) how far the held hands and feet are from their free trajectories (F,E,3), on average over the
    effectors held on each frame (``contacts`` (F,E), eased in and out over ±half_width frames): the shift
    that moves the body as its contacts moved, so that arms and legs share what is left to reach."""
    weight = moving_average(contacts.astype(np.float64), half_width)
    return np.einsum("fe,fei->fi", weight, targets - free) / np.maximum(weight.sum(axis=1), 1.0)[:, None]


def _blend_frames(path, free, start, stop, shortest, step):
    """(in, out) blend frames of a hold: at least ``shortest``, and long enough that moving between the free
    trajectory (F,3) and the held path goes at most about ``step`` per frame (smoothstep's steepest slope)."""
    first, last = (path, path) if np.ndim(path) == 1 else (path[0], path[-1])
    return tuple(max(shortest, int(np.ceil(1.5 * float(norm(p - free[f])) / step)))
                 for p, f in ((first, start), (last, stop - 1)))

