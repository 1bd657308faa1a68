"""Contacts of a motion: when a hand or foot touches the ground or an object (detection), and effector
trajectories held still at them, blended in and out (see solver/retarget/motion.py, step 2)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import SolverInputError
from ..maths.geometry import norm


def _check_numbers(settings, positive, at_least_zero):
    for name in positive + at_least_zero:
        v = getattr(settings, name)
        if not (isinstance(v, (int, float)) and np.isfinite(v) and (v > 0 if name in positive else v >= 0)):
            raise SolverInputError(f"{name} must be " + ("a positive number" if name in positive else "a number >= 0"))


@dataclass(frozen=True)
class ContactDetection:
    """What counts as a contact in the source. Speeds are per second and durations in seconds (so they hold
    at any frame rate), distances in source leg lengths (any unit, any performer's size).

    plant_speed: a hand or foot whose slowest point (wrist, ankle, heel, toes) moves slower than this may be
        in contact; plant_height: a foot touches the floor when its lowest point is within this of it;
    plant_min_duration: seconds a floor or object contact lasts at least (a run's stance is short);
    raised_min_duration: seconds a foot must stay still, off the floor and off every contact object, to be
        standing on something raised (a step, a rung, uneven ground) rather than turning in the air;
    gap_duration: a contact interrupted for at most this long is one contact;
    contact_distance: a still hand or foot within this of a contact object's box touches it;
    touch_distance: one this close touches it even while moving (a hand swinging on a bar)."""

    plant_speed: float = 0.3
    plant_height: float = 0.1
    plant_min_duration: float = 0.04
    raised_min_duration: float = 0.12
    gap_duration: float = 0.1
    contact_distance: float = 0.08
    touch_distance: float = 0.05

    def __post_init__(self):
        _check_numbers(self, ("plant_speed", "plant_height", "contact_distance"),
                       ("plant_min_duration", "raised_min_duration", "gap_duration", "touch_distance"))


@dataclass(frozen=True)
class RetargetSettings:
    """fps: frames per second of the timeline;
    blend_duration: seconds over which a held contact blends in and out of the free trajectory at least (and
        the window over which the body's shift is smoothed); blend_speed: the blend lasts longer where the
        held point is far from the free one, so the effector moves there at most about this fast (leg
        lengths per second): no jump on a character of another size;
    reach_margin: where a hand or foot target lies beyond its limb's reach (upper arm + forearm from the
        shoulder, thigh + shin from the hip) less this fraction, the whole body shifts, smoothly from frame to
        frame, just far enough (feet first): otherwise, frame by frame, a target just inside the reach leaves
        the root and chest where they are and one just beyond moves them, and the body pops;
    settle_margin: after smoothing the shift, each target is within its reach less this fraction;
    exact: hands on objects go to the source's own world positions and feet on raised supports to their
        world height (otherwise both scaled like the rest of the motion); soles on the floor are always on it;
    detection: what counts as a contact (ContactDetection)."""

    fps: float = 24.0
    blend_duration: float = 0.1
    blend_speed: float = 1.0
    reach_margin: float = 0.03
    settle_margin: float = 0.015
    exact: bool = True
    detection: ContactDetection = ContactDetection()

    def __post_init__(self):
        _check_numbers(self, ("fps", "blend_speed"), ("blend_duration", "reach_margin", "settle_margin"))
        if not isinstance(self.detection, ContactDetection):
            raise SolverInputError("detection must be a ContactDetection")

    def frames(self, seconds):
        return max(int(round(seconds * self.fps)), 1)


GROUND, RAISED, OBJECT = "ground", "raised", "object"


@dataclass(frozen=True)
class Contact:
    """One contact of one effector over frames [start, stop): ``kind`` GROUND (a foot on the floor), RAISED
    (a foot still on something higher that is not a contact object) or OBJECT (on box ``box``); ``surface``
    the world height a foot rests on (the floor, or where its lowest point rests; NaN for a hand)."""

    effector: str
    start: int
    stop: int
    kind: str
    surface: float = float("nan")
    box: int = -1


def intervals(mask, min_length=1, max_gap=0):
    """[(start, stop)] half-open runs of True in ``mask`` (F,): runs separated by at most ``max_gap`` frames
    are joined (a contact flickering for a frame or two is one contact), then runs shorter than
    ``min_length`` dropped."""
    mask = np.asarray(mask, dtype=bool)
    edges = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    runs = [[int(a), int(b)] for a, b in zip(np.nonzero(edges == 1)[0], np.nonzero(edges == -1)[0])]
    joined = []
    for run in runs:
        if joined and run[0] - joined[-1][1] <= max_gap:
            joined[-1][1] = run[1]
        else:
            joined.append(run)
    return [(a, b) for a, b in joined if b - a >= min_length]


def _speeds(points, fps):
    """(F,) speed per second of the slowest of the points (F,P,3): central differences, and towards whichever
    neighbouring frame it moves less (a foot coming to rest on that frame, or leaving from it)."""
    if len(points) < 2:
        return np.zeros(len(points)), np.zeros(len(points))
    steps = norm(np.diff(points, axis=0))  # (F-1,P)
    either = np.minimum(np.concatenate([steps[:1], steps]), np.concatenate([steps, steps[-1:]]))
    return norm(np.gradient(points, axis=0)).min(axis=-1) * fps, either.min(axis=-1) * fps


def box_distance(points, mins, maxs):
    """Distance (…,K) from points (…,3) to each closed box (K,3)/(K,3) (0 inside)."""
    p = np.asarray(points, dtype=np.float64)[..., None, :]
    gap = np.maximum(np.maximum(mins - p, p - maxs), 0.0)
    return norm(gap)


def detect_contacts(effector, points, ground, boxes, leg, settings=RetargetSettings()):
    """The contacts [Contact] of one effector, from its world points (F,P,3) in the source (wrist or ankle
    first, then the rest of the hand or foot), Z up. ``ground``: the floor's world height, or None when the
    floor is not a contact; ``boxes``: (mins, maxs) (K,3) world boxes of contact objects, or None. A frame's
    contact is, in this order: the nearest box it touches (hands and feet), the floor (feet), something raised
    (feet). Each kind's runs bridge gaps up to gap_duration; a frame taken by one kind is not another's."""
    points = np.asarray(points, dtype=np.float64)
    frames = len(points)
    foot = effector.startswith("foot")
    rule = settings.detection
    central, either = _speeds(points, settings.fps)
    still, arriving = central < rule.plant_speed * leg, either < rule.plant_speed * leg
    lowest = points[..., 2].min(axis=1)
    short = settings.frames(rule.plant_min_duration)
    gap = settings.frames(rule.gap_duration)
    taken = np.zeros(frames, dtype=bool)
    found = []

    def claim(mask, min_length, make, near=True):
        for a, b in intervals(mask & ~taken, min_length, gap):
            a, b = _trim(taken, a, b)
            if b - a >= min_length:
                a, b = _edges(a, b, arriving & near & ~taken)
                taken[a:b] = True
                found.append(make(a, b))

    if boxes is not None and len(boxes[0]):
        distance = box_distance(points, *boxes).min(axis=1)  # (F,K)
        nearest = distance.argmin(axis=1)
        closest = distance[np.arange(frames), nearest]
        touching = (closest <= rule.contact_distance * leg) & (still | (closest <= rule.touch_distance * leg))
        for k in range(len(boxes[0])):
            claim(touching & (nearest == k), short, lambda a, b, k=k: Contact(
                effector, a, b, OBJECT, float(lowest[a:b].mean()) if foot else float("nan"), k))
    if foot and ground is not None:
        low = lowest <= ground + rule.plant_height * leg
        claim(still & low, short, lambda a, b: Contact(effector, a, b, GROUND, float(ground)), low)
    if foot:
        claim(still, settings.frames(rule.raised_min_duration),
              lambda a, b: Contact(effector, a, b, RAISED, float(lowest[a:b].mean())))
    return sorted(found, key=lambda c: c.start)


def _edges(a, b, arriving):
    """[a, b) with the frame before it and the frame after it where ``arriving`` (F,) holds there: the frame a foot
    comes to rest on and the one it leaves from (the step on their other side fast, so central differences, the
    mean of both steps, leave them out) are the contact's, and its plant is held from the first."""
    return a - int(a > 0 and arriving[a - 1]), b + int(b < len(arriving) and arriving[b])


def _trim(taken, a, b):
    """The longest stretch of [a, b) not yet taken (a bridged run may reach over another kind's contact)."""
    free = ~taken[a:b]
    best = (a, a)
    for s, e in intervals(free):
        if e - s > best[1] - best[0]:
            best = (a + s, a + e)
    return best


def hold(free, holds, blend):
    """Trajectory (F,3): ``free`` (F,3), with each hold (start, stop, path[, (blend_in, blend_out)]) of
    ``holds`` following ``path`` (a point (3,) or one per frame (stop-start,3)) over [start, stop), blended in
    and out over ``blend`` frames either side (or the hold's own blend_in before and blend_out after;
    smoothstep weights), never into another hold's frames. What is blended is the hold's offset from the free
    trajectory where the hold begins (before it) or ends (after it), carried along the free trajectory: the
    effector keeps the free motion and moves at most 1.5 |offset| / (blend + 1) further per frame, however
    fast the free trajectory runs towards or away from the held point. Where the blends of two holds overlap,
    their offsets are averaged by weight, so the result is continuous wherever two holds are apart."""
    free = np.asarray(free, dtype=np.float64)
    if not holds:
        return free.copy()
    f = np.arange(len(free))
    total = np.zeros(len(free))
    weighted = np.zeros(free.shape)
    inside = []
    for h in holds:
        start, stop, path = h[:3]
        blend_in, blend_out = h[3] if len(h) > 3 else (blend, blend)
        # A blend ends where another hold begins: inside its interval, a hold alone sets the trajectory.
        blend_in = min([blend_in] + [start - o[1] for o in holds if o[1] <= start])
        blend_out = min([blend_out] + [o[0] - stop for o in holds if o[0] >= stop])
        outside = np.maximum((start - f) / (blend_in + 1.0), (f - (stop - 1)) / (blend_out + 1.0))
        x = np.clip(1.0 - np.maximum(outside, 0.0), 0.0, 1.0)
        w = x * x * (3.0 - 2.0 * x)
        path = np.asarray(path, dtype=np.float64)
        within = np.clip(f, start, stop - 1)
        extended = path if path.ndim == 1 else path[within - start]
        total += w
        weighted += w[:, None] * (extended - free[within])
        inside.append((start, stop, extended[start:stop] if path.ndim > 1 else path))
    out = free + np.minimum(total, 1.0)[:, None] * (weighted / np.maximum(total, 1e-300)[:, None])
    for start, stop, path in inside:
        out[start:stop] = path  # exactly the held path (free + offset rounds)
    return out
