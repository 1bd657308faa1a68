"""Contacts of a motion: when a hand or foot touches the ground or an object (detection), and effector
trajectories held still at them, blended in and out (see solver/retarget.py, step 2)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .errors import SolverInputError
from .geometry import norm


@dataclass(frozen=True)
class RetargetSettings:
    """fps: frames per second of the timeline (speeds are per second);
    plant_speed: a foot (or a hand on an object) moving slower than this many source leg lengths per second
        may be in contact; plant_height: a planted ankle is within this many leg lengths of its lowest height
        in the range; plant_min_duration: seconds a contact must last;
    contact_distance: an effector within this many leg lengths of a contact box touches it;
    blend_duration: seconds over which a held contact blends in and out of the free trajectory (and the
        window over which the body's shift is smoothed);
    reach_margin: where a hand or foot target lies beyond its limb's reach (upper arm + forearm from the
        shoulder, thigh + shin from the hip) less this fraction, the whole body shifts, smoothly from frame to
        frame, just far enough (feet first): otherwise, frame by frame, a target just inside the reach leaves
        the root and chest where they are and one just beyond moves them, and the body pops;
    settle_margin: after smoothing the shift, each target is within its reach less this fraction;
    exact: contacts go exactly to the ground / the source's world positions (module docstring)."""

    fps: float = 24.0
    plant_speed: float = 0.3
    plant_height: float = 0.08
    plant_min_duration: float = 0.1
    contact_distance: float = 0.15
    blend_duration: float = 0.1
    reach_margin: float = 0.03
    settle_margin: float = 0.015
    exact: bool = False

    def __post_init__(self):
        for name in ("fps", "plant_speed", "plant_height", "contact_distance"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and np.isfinite(v) and v > 0):
                raise SolverInputError(f"{name} must be a positive number")
        for name in ("plant_min_duration", "blend_duration", "reach_margin", "settle_margin"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and np.isfinite(v) and v >= 0):
                raise SolverInputError(f"{name} must be a number >= 0")

    def frames(self, seconds):
        return max(int(round(seconds * self.fps)), 1)


def still_frames(positions, fps, max_speed):
    """(F,) bool: the point (F,3) moves slower than ``max_speed`` per second (central differences)."""
    positions = np.asarray(positions, dtype=np.float64)
    if len(positions) < 2:
        return np.ones(len(positions), dtype=bool)
    speed = norm(np.gradient(positions, axis=0)) * fps
    return speed < max_speed


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


def _contact_runs(candidate, settings):
    n = settings.frames(settings.plant_min_duration) if settings.plant_min_duration else 1
    return intervals(candidate, n, max_gap=n)


def detect_plants(ankles, up, fps, leg, settings=RetargetSettings()):
    """Planted intervals of one foot: ankle positions (F,3) (world; ``up`` the index of the vertical axis),
    still (slower than plant_speed·leg per second) and within plant_height·leg of the foot's lowest height,
    for at least plant_min_duration (shorter interruptions are bridged). Returns [(start, stop)]."""
    ankles = np.asarray(ankles, dtype=np.float64)
    height = ankles[:, up]
    low = np.percentile(height, 2) if len(height) else 0.0
    candidate = still_frames(ankles, fps, settings.plant_speed * leg) & (height <= low + settings.plant_height * leg)
    return _contact_runs(candidate, settings)


def box_distance(points, mins, maxs):
    """Distance (…,K) from points (…,3) to each closed box (K,3)/(K,3) (0 inside)."""
    p = np.asarray(points, dtype=np.float64)[..., None, :]
    gap = np.maximum(np.maximum(mins - p, p - maxs), 0.0)
    return norm(gap)


def detect_object_contacts(points, mins, maxs, fps, leg, settings=RetargetSettings()):
    """Intervals [(start, stop)] where the point (F,3) is still and within contact_distance·leg of a box."""
    if len(mins) == 0:
        return []
    near = box_distance(points, mins, maxs).min(axis=-1) <= settings.contact_distance * leg
    still = still_frames(points, fps, settings.plant_speed * leg)
    return _contact_runs(near & still, settings)


def hold(free, holds, blend):
    """Trajectory (F,3): ``free`` (F,3), with each (start, stop, point) of ``holds`` held at ``point`` over
    [start, stop) and blended in/out over ``blend`` frames either side (smoothstep weights); where the blends
    of two holds overlap, their points are averaged by weight, so the result is continuous."""
    free = np.asarray(free, dtype=np.float64)
    if not holds:
        return free.copy()
    f = np.arange(len(free))
    weights = []
    for start, stop, _ in holds:
        outside = np.maximum(np.maximum(start - f, f - (stop - 1)), 0) / (blend + 1.0)
        x = np.clip(1.0 - outside, 0.0, 1.0)
        weights.append(x * x * (3.0 - 2.0 * x))
    weights = np.stack(weights)  # (H,F)
    points = np.stack([np.asarray(p, dtype=np.float64) for _, _, p in holds])
    total = weights.sum(axis=0)
    mix = (weights.T @ points) / np.maximum(total, 1e-300)[:, None]
    amount = np.minimum(total, 1.0)[:, None]
    return free + amount * (mix - free)
