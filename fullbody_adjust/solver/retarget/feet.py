"""How far a target's foot rolls onto its toes, and how high the body stands over its feet (resting_offsets,
raised_offsets; refit_step: the feet refitted to the solved pose) (see solver/retarget/motion.py, step 2).

Transferred as rotations, a target's foot pitches as the source's does. As a foot rolls onto its toes (toe-off)
its ankle rises above the point it stands on by about the foot's length times the sine of the pitch, so a foot
longer than the source's (for its leg: KayKit's, whose ankle stands 40% of a leg above its sole, against a
tenth for a person) would dig its toes into the floor where the source's stand on it, and the floor lifting
the ankle out of it in a frame or two bends the knee far more than the source's (KayKit's shin turning over 30
degrees in a frame, where the source's turned 10). The leg is what the source's motion is about, so the foot
gives way instead: it rolls onto its toes only as far as lifts its ankle above its sole as much as the source's
ankle rises above its own (scaled by the legs' ratio, from where each stands flat; the source's toes held as
the target's are, which keep their own pose), and, where it is not held on the floor, no further than keeps
its sole above the floor. It is turned back toes up about its ankle, never past how it stands flat: a longer
foot pitches less, and the leg moves as the source's does.
"""

from __future__ import annotations

import numpy as np

from .foot_pivots import ball_bone
from ..maths.geometry import cross, dot, norm
from .rig import FEET, ankle_above_sole
from .soles import descendants

_UP = np.array([0.0, 0.0, 1.0])
# How far above the world's ground plane (in leg lengths) a source's lowest joints may rest for that plane to be
# its floor: a foot's height at the ankle is about a seventh of a leg.
UNSEEN_FOOT = 0.15
_LARGEST_TURN = 0.5 * np.pi
_STANCE_PERCENTILE = 25  # the source's ankle at its lowest quarter: the foot stands flat on the floor
_STEPS = 40  # halvings of the bisection (1e-12 of a quarter turn)


def limit_toe_roll(source, source_pose, target, pose, ratio, clearance=None):
    """Turn each target foot of ``pose`` (F,Jt,4,4, armature space, changed in place: the foot bone and every
    bone below it, about the ankle) toe up where it rolls onto its toes further than the source's allows (see
    the module docstring), measured from the frames where the source's foot stands flat (its ankle at its lowest
    quarter of heights: mid-stance, between the heel strike and the heel rising); and, where ``clearance`` (F,2)
    says how high above the floor each ankle will be (inf: no bound, as on frames a foot is held), no further
    than takes its sole below the floor. ``source_pose`` (F,Js,4,4); ``ratio``: target leg / source leg. Returns
    the angles (F,2) (radians) each foot was turned by."""
    frames = len(pose)
    turned = np.zeros((frames, len(FEET)))
    s_above = ankle_above_sole(source, _rigid_toes(source, source_pose))
    t_above = ankle_above_sole(target, pose)
    forward = _body_forward(target, pose)
    for i, foot in enumerate(FEET):
        if foot not in target.groups or foot not in source.groups:
            continue
        s_ankle = source.to_world(source_pose[:, source.groups[foot][0], :3, 3])[:, 2]
        rest = s_ankle <= np.percentile(s_ankle, _STANCE_PERCENTILE)
        allowed = np.median(t_above[rest, i]) + ratio * (s_above[:, i] - np.median(s_above[rest, i]))
        if clearance is not None:
            allowed = np.minimum(allowed, clearance[:, i])
        ankle_bone = target.groups[foot][0]
        ankle = target.to_world(pose[:, ankle_bone, :3, 3])
        ahead = _foot_axis(target, pose, foot, ankle)
        pitch = np.arctan2(-ahead[:, 2], dot(ahead, forward))  # toes below the ankle: > 0; pointing back: > 90°
        room = np.clip(pitch - np.median(pitch[rest]), 0.0, _LARGEST_TURN)  # never flatter than it stands
        over = (t_above[:, i] > allowed + 1e-9 * max(float(np.abs(t_above[:, i]).max()), 1e-300)) & (room > 0.0)
        if not over.any():
            continue
        sole = target.sole_points(pose[over], foot) - ankle[over, None]  # (n,P,3) from the ankle
        angle = _toe_up_angle(sole, forward[over], allowed[over], room[over])
        turned[over, i] = angle
        _turn_below(target, pose, np.nonzero(over)[0], ankle_bone, ankle[over], cross(forward[over], _UP), angle)
    return turned


def _rigid_toes(rig, pose):
    """A copy of ``pose`` (F,J,4,4) with every bone below each ankle held as at rest relative to the foot (the
    target's toes do not bend: they keep their own pose, transfer)."""
    out = np.array(pose, dtype=np.float64)
    for foot in FEET:
        if foot not in rig.groups:
            continue
        ankle = rig.groups[foot][0]
        below = rig.descendants(ankle)[1:]
        out[:, below] = out[:, ankle, None] @ (np.linalg.inv(rig.rest[ankle]) @ rig.rest[below])
    return out


def _body_forward(rig, pose):
    """(F,3) horizontal unit direction the body faces (square across its hip joints, as solver/facing.py reads
    it) in armature-space pose matrices (F,J,4,4)."""
    heads = rig.to_world(pose[..., :3, 3])
    left = heads[:, rig.groups["leg.L"][0]] - heads[:, rig.groups["leg.R"][0]]
    forward = cross(left, _UP) * [1.0, 1.0, 0.0]
    return forward / np.maximum(norm(forward), 1e-300)[:, None]


def _foot_axis(rig, pose, foot, ankle):
    """(F,3) world direction along the foot: ankle to ball, else to its sole's middle."""
    ball = ball_bone(rig, foot)
    if ball is not None:
        return rig.to_world(pose[:, ball, :3, 3]) - ankle
    return rig.sole_points(pose, foot).mean(axis=1) - ankle


def _toe_up_angle(sole, forward, allowed, room):
    """(n,) least angle (radians, within ``room`` (n,)) turning the sole points (n,P,3, from the ankle) about the
    horizontal axis ``forward`` (n,3) x up (toes up) so that none lies more than ``allowed`` (n,) below the
    ankle (all of ``room`` where that is not enough). A point at height x and distance w ahead lies at
    x cos t + w sin t after a turn by t: turning a foot whose toes point down back towards how it stands flat
    raises its lowest point."""
    x = sole[..., 2]
    w = np.einsum("npi,ni->np", sole, forward)

    def depth(t):
        return -(x * np.cos(t)[:, None] + w * np.sin(t)[:, None]).min(axis=1)

    lo, hi = np.zeros(len(x)), np.asarray(room, dtype=np.float64).copy()
    for _ in range(_STEPS):  # bisection: the depth falls as the toes come up
        mid = 0.5 * (lo + hi)
        enough = depth(mid) <= allowed
        lo, hi = np.where(enough, lo, mid), np.where(enough, mid, hi)
    return hi


def _turn_below(rig, pose, frames, bone, pivot, axes, angles):
    """Turn ``bone`` and every bone below it in ``pose`` (F,J,4,4, armature space, in place) on ``frames`` (n,)
    about the world point ``pivot`` (n,3) and world ``axes`` (n,3) by ``angles`` (n,)."""
    axes = axes / np.maximum(norm(axes), 1e-300)[:, None]
    c, s = np.cos(angles)[:, None, None], np.sin(angles)[:, None, None]
    k = np.zeros((len(axes), 3, 3))
    k[:, 0, 1], k[:, 0, 2], k[:, 1, 2] = -axes[:, 2], axes[:, 1], -axes[:, 0]
    k -= np.swapaxes(k, -1, -2)
    world = np.eye(3) + s * k + (1.0 - c) * (k @ k)  # Rodrigues
    turn = rig.rotation.T @ world @ rig.rotation  # the same turn in armature space
    centre = rig.to_armature(pivot)
    move = np.tile(np.eye(4), (len(frames), 1, 1))
    move[:, :3, :3] = turn
    move[:, :3, 3] = centre - np.einsum("nij,nj->ni", turn, centre)
    bones = descendants(rig.parents, bone)
    pose[np.ix_(frames, bones)] = move[:, None] @ pose[np.ix_(frames, bones)]


def resting_offsets(ankles, s_points, soles, floor, leg, settings):
    """{foot index: how far (world z) its ankle must move so that its sole is on the floor on the frames the
    source's is lowest (its lower half, the median there)}, of the feet that come down to the floor there (the
    source's soles within the plant height, and UNSEEN_FOOT, of it). ``ankles`` (F,2): the target's ankle
    heights; ``soles`` (F,2): its ankles above their soles; ``s_points``: the source's effector points; ``leg``:
    the source's leg length.

    Scaled with the legs (hip joint to ankle), the target's ankles come down where the source's do, but each rig
    has its own foot below the ankle: one whose ankle stands higher above its sole than the scaled source's would
    stand in the floor (KayKit's and Godot's plush characters by a seventh to a quarter of a leg on Kenney's run),
    and lifting its feet out of it bends its knees far more than the source's, most where the source's leg is
    nearly straight. The body moves by the feet's mean offset instead, its legs as straight as the source's."""
    near = floor + (settings.detection.plant_height + UNSEEN_FOOT) * leg
    out = {}
    for i, (e, resting) in enumerate(zip(FEET, resting_frames(s_points).T)):
        if np.median(s_points[e][resting, 1:, 2].min(axis=1)) <= near:
            out[i] = float(np.median((floor + soles[:, i] - ankles[:, i])[resting]))
    return out


def raised_offsets(ankles, s_points, soles, floor, ratio):
    """resting_offsets of a clip neither of whose feet comes down to the floor on the frames it is lowest (a
    climb from bar to bar, a sit): {foot index: how far (world z) its ankle must move so that its sole is where
    the source's is there, scaled about the floor by the legs' ``ratio``}. A raised support is held at its height
    scaled so (_at_world_height), the target's own foot below it: Godot's plush, its ankle 0.25 m above its sole
    on a 0.36 m leg (the scaled CMU foot's 3 cm), stood on the climb's bars with its knees folded to their limit
    (163 degrees, the transferred 90 to 100) and missed them."""
    out = {}
    for i, (e, resting) in enumerate(zip(FEET, resting_frames(s_points).T)):
        sole = floor + ratio * (s_points[e][resting, 1:, 2].min(axis=1) - floor)
        out[i] = float(np.median((sole + soles[resting, i] - ankles[resting, i])))
    return out


def resting_frames(s_points):
    """(F,2) bool: per foot, the frames its sole is lowest in the source (the lower half of its heights)."""
    low = np.stack([s_points[e][:, 1:, 2].min(axis=1) for e in FEET], axis=1)
    return low <= np.percentile(low, 50, axis=0)


def refit_step(moved, before, tiny):
    """How far to move targets that a refit moved by ``moved`` after moving them by ``before`` (arrays alike).
    Where the feet hang on the knee (a heel skinned to the shin: the ankle lowered, the knee bends and the sole
    sinks further), each refit moves a target by a fraction ``ratio`` of the one before, and alternately up and
    down (KayKit's crouch: -0.67), so plain refits stop millimetres short. Taken as steady, the series sums to
    moved / (1 - ratio) (Aitken's step), where the refits shrink: a ratio in [-0.95, 0.5] (at most twice
    ``moved`` where they creep one way). Elsewhere (a refit moving a target further than the one before: the
    sole's lowest point changed, not a steady series; or ``before`` under ``tiny``), the plain refit."""
    ratio = np.where(np.abs(before) > tiny, moved / np.where(np.abs(before) > tiny, before, 1.0), 0.0)
    steady = (ratio >= -0.95) & (ratio <= 0.5)
    return moved / (1.0 - np.where(steady, ratio, 0.0))


def lowered_within_reach(ankles, hips, by, longest):
    """(F,) how far to move a free foot's ankle (``ankles`` (F,3)) up or down to move it by ``by`` (world z) without
    taking it farther from its hip joint (``hips`` (F,3)) than ``longest`` or than it already is, whichever is
    farther: lowered onto the floor as a whole (plan._stand_in_place), a foot the source's leg nearly straightens
    to would stretch it straight, and the knee snap back as it bends (KayKit's run onto Kenney: 12.7 degrees
    bent in the clip, 4.3 with the foot 7 mm lower, the shin turning 30.6 degrees on the next frame, the clip's
    26.5). Raised, or with room to spare, it moves by ``by``."""
    ankles, hips = np.asarray(ankles, dtype=np.float64), np.asarray(hips, dtype=np.float64)
    if by >= 0.0:
        return np.full(len(ankles), float(by))
    apart = hips - ankles
    farthest = np.maximum(norm(apart), longest)
    room = np.sqrt(np.maximum(farthest ** 2 - norm(apart[:, :2]) ** 2, 0.0)) - apart[:, 2]  # lower by at most
    return -np.minimum(-by, np.maximum(room, 0.0))
