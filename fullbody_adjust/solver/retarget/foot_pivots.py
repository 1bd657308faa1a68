"""Which point of a planted foot stays where it is from one frame to the next.

A viewer sees a plant held when the joint the foot stands on does not slide: the ball of the foot while the heel
lifts (the foot turns about the joint at the root of the toes, the toes flat on the ground), the ankle on a foot
without toes. So on the frames where the SOURCE holds that joint still near the floor, the target's own joint is
the pivot (it keeps its place on the floor, whatever its sole does); where the source holds its ankle still but
not its ball (standing on the heel, the toes turning or raised: a dancer's swivel; on the ball, the toes
twitching), the target's ankle stays;
elsewhere in a contact the foot rolls about the lowest point of its sole (heel strike, toes pushing off: the point
on the ground)."""

from __future__ import annotations

import numpy as np

from .contacts import intervals
from ..maths.geometry import norm

# How much higher than a plant's height above its lowest place a ball held still may stand while the foot pitches
# onto its toes (pivot_held).
_PIVOT_RISE = 1.5
# How much more than its ankle (in plant heights) a ball held still may have risen and still be what the foot stands
# on (pivot_held): more, and the foot stands on its heel, toes up.
_HEEL_STAND = 0.5


def ball_bone(rig, foot):
    """The bone at the ball of a foot (its head is the joint at the root of the toes): of the bones whose parent
    is the foot's ankle bone, the one whose rest head lies farthest from the ankle's (the toes; a heel bone
    is nearer); None for a foot with no bone below it."""
    ankle = rig.groups[foot][0]
    children = np.nonzero(rig.parents == ankle)[0]
    if not len(children):
        return None
    heads = rig.rest[:, :3, 3]
    distance = norm(heads[children] - heads[ankle])
    if not distance.max() > 0.0:
        return None
    return int(children[int(np.argmax(distance))])


def pivot_bone(source, target, foot):
    """(source bone, target bone) of the joint a planted foot pivots about, the target's held where the source's
    is still: the ball where both rigs have one; the target's ankle where it has no ball, held where the source's
    ball is (a foot without toes comes down as the source's does about its ball: rolled about its sole instead,
    Godot's robot's ankle slid 46 mm as it landed from the climb); else the ankles."""
    balls = ball_bone(source, foot), ball_bone(target, foot)
    if balls[0] is None:
        return source.groups[foot][0], target.groups[foot][0]
    return balls[0], target.groups[foot][0] if balls[1] is None else balls[1]


def _rise(points):
    """(F,) how high a joint's track (F,3) stands above its lowest place in the clip (the 2nd percentile of its
    heights: a stumble below the floor is not where it stands)."""
    return points[:, 2] - np.percentile(points[:, 2], 2)


def held_still(points, fps, speed, height):
    """(F,) bool: the frames where a joint's world track ``points`` (F,3) moves slower than ``speed`` (world units
    a second) towards either neighbouring frame, within ``height`` of its lowest place in the clip (the 2nd
    percentile of its heights: a stumble below the floor is not where it stands). A frame the joint comes to rest
    on, or leaves from, is still as a viewer sees it (the step on its other side may be fast): central
    differences, the mean of both steps, left the first and last frames of a plant out, and the foot turned
    about its sole there, its ball sliding 3 to 16 mm on a CMU walk."""
    points = np.asarray(points, dtype=np.float64)
    if len(points) < 2:
        return np.zeros(len(points), dtype=bool)
    steps = norm(np.diff(points, axis=0)) * fps
    moving = np.minimum(np.concatenate([steps[:1], steps]), np.concatenate([steps, steps[-1:]]))
    low = _rise(points) <= height
    return (moving < speed) & low


def pivot_held(pivot, ankle, fps, speed, height):
    """(F,) bool: the frames a foot stands on its ``pivot`` joint (F,3: the ball; the ankle ``ankle`` (F,3)), held
    still (held_still) within ``height`` of its lowest place and risen no more than _HEEL_STAND of that above what
    the ankle has risen above its own lowest place, or within _PIVOT_RISE times ``height`` where it has risen no
    more than the ankle: a ball held still while the heel lifts and the foot pitches onto its toes rises with the
    foot's thickness (KayKit's sneak: 4-6 cm, its ball sliding 12 mm as the foot turned about its toe tip instead),
    where a heel stand raising the toes (a dancer's swivel) lifts the ball more than the ankle, and the ankle is
    what stays (the CMU dance's right foot on its heel, toes 8 cm up: turned about its ball, Godot's plush's ankle
    slid 38 mm)."""
    pivot, ankle = np.asarray(pivot, dtype=np.float64), np.asarray(ankle, dtype=np.float64)
    if not len(pivot):
        return np.zeros(0, dtype=bool)
    toes_down = _rise(pivot) <= _rise(ankle)
    nearly = _rise(pivot) <= _rise(ankle) + _HEEL_STAND * height
    return (held_still(pivot, fps, speed, height) & nearly) | (held_still(pivot, fps, speed, _PIVOT_RISE * height)
                                                             & toes_down)


def ankle_held(ankle, pinned, fps, speed, height, shortest):
    """(F,) bool: the frames the source holds its ankle (F,3) still (held_still, at any height), in runs of at least
    ``shortest`` frames, but those where it is within ``height`` of its lowest place and the ball is held (``pinned``:
    pivot_held): where the ball is not held on both frames of a step, the target's ankle stays (roll). Held high: on
    the ball, heel up, a dancer's toes twitching 3-4 cm a frame about a still ankle (the CMU dance) turned the
    metarig's foot about its sole's lowest point, its ankle swinging 6-7 cm a frame (2 pop frames at 30 fps). Held
    low, the ball coming down: the foot rolls about its heel (held there, the ankle slid the shoe's heel: a walk's
    sliding p95 0.4 -> 1.6 mm). A frame or two between the heel strike and the ball coming down is a foot rolling
    about its heel, not one standing on it."""
    ankle = np.asarray(ankle, dtype=np.float64)
    low = _rise(ankle) <= height if len(ankle) else np.zeros(0, dtype=bool)
    out = np.zeros(len(ankle), dtype=bool)
    for a, b in intervals(held_still(ankle, fps, speed, np.inf) & ~(low & np.asarray(pinned, dtype=bool)), shortest):
        out[a:b] = True
    return out


def roll(ankle, sole, pivot, pinned, tolerance, ankle_pinned=None):
    """(n,2) horizontal travel of a planted foot's ankle from its first frame, that keeps its pivot in place:
    ``ankle`` (n,3), ``sole`` (n,P,3) the foot as posed on each frame; from each frame to the next the foot
    turns about ``pivot`` (n,3: the joint it stands on) where ``pinned`` (n,) holds on both frames, else about
    its ankle where ``ankle_pinned`` (n,) holds on both (the ankle stays), else about the lowest point of its sole
    (points within ``tolerance`` of the lowest by their mean: a flat heel's two ends turn it about neither)."""
    n = len(ankle)
    if n < 2:
        return np.zeros((n, 2))
    rel = ankle[:, None, :2] - sole[..., :2]  # (n,P,2) ankle less each sole point
    z = sole[:-1, :, 2]
    weight = (z <= z.min(axis=1, keepdims=True) + tolerance).astype(np.float64)
    weight /= weight.sum(axis=1, keepdims=True)
    step = np.einsum("fp,fpi->fi", weight, rel[1:] - rel[:-1])
    about = ankle[:, :2] - pivot[:, :2]
    if ankle_pinned is not None:
        step[np.asarray(ankle_pinned[:-1], dtype=bool) & np.asarray(ankle_pinned[1:], dtype=bool)] = 0.0
    both = np.asarray(pinned[:-1], dtype=bool) & np.asarray(pinned[1:], dtype=bool)
    step[both] = (about[1:] - about[:-1])[both]
    return np.concatenate([np.zeros((1, 2)), np.cumsum(step, axis=0)])


def drifting_pieces(travel, free, held, largest):
    """[(start, stop)] half-open pieces of a foot contact of n frames to hold each on its own (the frames between
    them blend to the free trajectory), or [(0, n)] to hold it whole: ``travel`` (n,2) its ankle's horizontal
    travel as held (roll), ``free`` (n,2) its free trajectory, ``held`` (n,) the frames the source holds the foot's
    pivot or ankle still. Held whole, the path is centred on the free trajectory, which the source's motion moves
    as the source's own (smaller, or larger) foot turns: where the two part by more than ``largest`` (world) over the
    contact (a dancer's twist steps, the foot turning on ball and heel by turns), the target's leg cannot reach its
    held foot at the contact's ends (Godot's plush, its foot 0.4 of its leg long, its ankle 0.43 m from where the
    dance's scaled ankle went, its arms pulled off their hands), so each stretch the source holds still is held on
    its own: the first from the contact's start, the last to its stop."""
    n = len(free)
    offset = np.asarray(travel, dtype=np.float64) - np.asarray(free, dtype=np.float64)[:, :2]
    runs = intervals(held)
    if n == 0 or len(runs) < 2 or not float(norm(np.ptp(offset, axis=0))) > largest:
        return [(0, n)]
    return [(0 if i == 0 else a, n if i == len(runs) - 1 else b) for i, (a, b) in enumerate(runs)]
