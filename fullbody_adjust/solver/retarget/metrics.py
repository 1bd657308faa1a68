"""Measures of a retargeted motion: smoothness (pops show as spikes of the change of velocity), and how well
the result keeps the source's contacts (contact error, sliding, frames below the floor, frame-to-frame
pops), measured from world points of the result, not from the targets the solve was given."""

from __future__ import annotations

import numpy as np

from .contacts import OBJECT, box_distance
from ..maths.geometry import norm

# A step of an effector this much faster (leg lengths per second) than the source's own, scaled, is a pop.
POP_SPEED = 1.5
# Below the floor by more than this (leg lengths) counts: a sole exactly on it is not below it.
FLOOR_TOLERANCE = 0.002
# A contact is held when its error is at most this (leg lengths; a hand: beyond the source's own distance).
HOLD_TOLERANCE = 0.01


def roughness(positions, scale=1.0):
    """Per joint, the largest frame-to-frame change of velocity |p[f+1] - 2 p[f] + p[f-1]| / scale over the
    frames: positions (F,J,3) -> (J,). A pop shows as a spike far above the motion's own roughness."""
    positions = np.asarray(positions, dtype=np.float64)
    if len(positions) < 3:
        return np.zeros(positions.shape[1])
    second = positions[2:] - 2.0 * positions[1:-1] + positions[:-2]
    return norm(second).max(axis=0) / scale


def angular_roughness(rotations):
    """Per bone, the largest change of angular velocity between frames: the angle (radians) between
    consecutive frame-to-frame rotations, rotations (F,J,3,3) -> (J,)."""
    r = np.asarray(rotations, dtype=np.float64)
    if len(r) < 3:
        return np.zeros(r.shape[1])
    step = r[1:] @ np.swapaxes(r[:-1], -1, -2)  # (F-1,J,3,3) rotation from one frame to the next
    change = step[1:] @ np.swapaxes(step[:-1], -1, -2)
    cos = np.clip((np.trace(change, axis1=-2, axis2=-1) - 1.0) * 0.5, -1.0, 1.0)
    return np.arccos(cos).max(axis=0)


def contact_errors(contact, points, boxes):
    """(n,) error over a contact's frames of an effector's world points (n,P,3) (wrist or ankle first): a
    foot, how far its lowest point is from the surface it rests on; a hand on an object, the distance of
    its nearest point to the object's box."""
    points = np.asarray(points, dtype=np.float64)
    if _hand_on_object(contact):
        k = slice(contact.box, contact.box + 1)
        return box_distance(points, boxes[0][k], boxes[1][k])[..., 0].min(axis=1)
    return np.abs(points[..., 2].min(axis=1) - contact.surface)


def _hand_on_object(contact):
    return contact.kind == OBJECT and not np.isfinite(contact.surface)  # a foot on one rests on its surface


def sliding(points):
    """How far a planted foot slides over a contact, of its world points (n,P,3): from each frame to the
    next, the horizontal distance its stillest point moves (the one it turns about), summed. A foot rolling
    from heel to toes or turning on its heel does not slide; one dragged along the floor does."""
    points = np.asarray(points, dtype=np.float64)
    if len(points) < 2:
        return 0.0
    step = np.diff(points[..., :2], axis=0)
    return float(np.hypot(step[..., 0], step[..., 1]).min(axis=1).sum())


def step_lengths(points):
    """(F,) distance each point (F,3) moved since the frame before (0 on the first)."""
    points = np.asarray(points, dtype=np.float64)
    return np.concatenate([[0.0], norm(np.diff(points, axis=0))])


def contact_figures(contacts, points, source_points, boxes, ground, leg, ratio, fps, reachable=None):
    """Per effector, how the result keeps the source's contacts. ``contacts`` {effector: [Contact]} (the
    source's); ``points`` and ``source_points`` {effector: (F,P,3)} world points of the result's and the
    source's hand or foot (solver.retarget.rig.effector_points: the wrist or ankle, then the hand's joints or
    the foot's sole, which sliding is measured on); ``boxes`` the contact objects' (mins,
    maxs) or None; ``ground`` the floor's height or None; ``leg`` the result's leg length, ``ratio`` its
    ratio to the source's; ``reachable`` {effector: (F,) bool} frames whose target was within reach (None:
    all). Returns {effector: {...}} (see ``summary_of``) and per effector (F,) contact error (NaN outside
    contacts) for plotting."""
    figures, curves = {}, {}
    for e, pts in points.items():
        frames = len(pts)
        error = np.full(frames, np.nan)
        source_error = np.full(frames, np.nan)
        slides, not_held = [], np.zeros(frames, dtype=bool)
        for c in contacts.get(e, ()):
            a, b = c.start, c.stop
            error[a:b] = contact_errors(c, pts[a:b], boxes)
            source_error[a:b] = contact_errors(c, source_points[e][a:b], boxes)
            allowed = HOLD_TOLERANCE * leg + (source_error[a:b] if _hand_on_object(c) else 0.0)
            not_held[a:b] = error[a:b] > allowed
            if e.startswith("foot"):
                slides.append(sliding(pts[a:b, 1:]))  # the sole's points (the ankle turns about them)
        if reachable is not None:
            not_held &= reachable[e]
        steps = step_lengths(pts[:, 0])
        pops = steps > ratio * step_lengths(source_points[e][:, 0]) + POP_SPEED * leg / fps
        on_floor = ground is not None and e.startswith("foot")
        depth = ground - pts[..., 2].min(axis=1) if on_floor else np.zeros(frames)
        below = depth > FLOOR_TOLERANCE * leg
        figures[e] = {
            "contacts": [{"kind": c.kind, "start": c.start, "stop": c.stop} for c in contacts.get(e, ())],
            "contact_frames": int(np.isfinite(error).sum()),
            "contact_error": _stats(error[np.isfinite(error)]),
            "source_contact_error": _stats(source_error[np.isfinite(source_error)]),
            "not_held_frames": int(not_held.sum()),
            "sliding": _stats(np.array(slides)),
            "frames_below_floor": int(below.sum()),
            "deepest_below_floor": float(max(0.0, depth.max(initial=0.0))),
            "largest_step": float(steps.max()) if frames else 0.0,
            "pops": int(pops.sum()),
        }
        curves[e] = error
    return figures, curves


def _stats(values):
    values = np.asarray(values, dtype=np.float64).reshape(-1)
    if values.size == 0:
        return {"count": 0, "median": None, "p95": None, "max": None}
    return {"count": int(values.size), "median": float(np.median(values)), "p95": float(np.percentile(values, 95)),
            "max": float(values.max())}
