"""Where a skeleton faces at rest, from its leg joints alone (never its object's axes, never the tails an importer
left): the one calculation behind the bone mapping's sides (bone_mapping/body_sides.py), the retarget's heading
(rig.rest_forward) and the side elbows and knees bend to (rest_hinges.rest_facing).

Up is given: world z for the mapping and the retarget, the hips -> shoulders direction for the rest hinges (which
work in armature space); "across" below means perpendicular to up. The hip joints give the lateral line (else the
knees, else the ankles); the body faces across it, on the side its toes point to (from each ankle, the joint
below the foot farthest from it across up), else the side its knees bend to (a knee's offset from its hip - ankle
line), the foot bones' own directions a last hint. That side is the facing's ``sign``, ``clear`` when the toes of
both feet agree, or both knees and both foot bones do. When the caller knows which leg is the character's left
(``left``), that gives the side instead and the joints only turn the forward:

forward = the toes' mean direction when it lies within 60 degrees of the side across the hip line (the feet say
where a character looks and walks even when its hips are yawed: GDQuest's mannequin has its hip and shoulder
lines 13 degrees off its face and toes), else square across the hip line on that side. Left = up x forward.
"""

from dataclasses import dataclass

import numpy as np

UP = np.array([0.0, 0.0, 1.0])

_TOE_REACH = 0.1  # a toe joint lies at least this many leg lengths from the ankle, across up
_TOE_CLEAR = 0.5  # cosine between a foot's toes (or foot bone) and the side across the hips, for a clear vote
_TOES_AHEAD = 0.5  # cosine (60 degrees) within which the toes' mean direction turns the forward
_KNEE_BEND = 0.01  # a knee lies at least this many leg lengths off the hip - ankle line to count
_FOOT_FLAT = 0.3  # a foot bone's part across up is at least this fraction of its length to count


@dataclass(frozen=True)
class Facing:
    """``lateral``: unit vector across up from leg 1 to leg 0 (None: the legs are not side by side); the body
    faces ``sign`` * (up x lateral) (0: nothing says where), ``clear`` as in the module docstring; ``forward``:
    unit vector across up (None when neither the hips nor the toes say)."""

    lateral: np.ndarray | None
    sign: int
    clear: bool
    forward: np.ndarray | None


def across(up, v):
    """The part of v (…,3) perpendicular to the unit vector up."""
    v = np.asarray(v, dtype=np.float64)
    return v - (v @ up)[..., None] * up


def lateral(up, pairs, tiny):
    """Unit vector across up from the second point of the first pair (a, b) lying more than 10 tiny apart across
    up to its first (hip joints, else knees, else ankles), or None."""
    for a, b in pairs:
        d = across(up, np.asarray(a, dtype=np.float64) - b)
        size = float(np.linalg.norm(d))
        if size > 10 * tiny:
            return d / size
    return None


def skeleton_facing(up, hips, ankles, below, tiny, knees=None, feet=None, left=None):
    """Facing of two legs (module docstring): ``hips``, ``ankles`` and ``knees`` (2,3) their joints (knees None:
    no vote from them), ``below`` per leg the joints (P,3) below its ankle (the foot's descendants), ``feet``
    per leg its foot bone's direction (3,) or None; ``tiny`` the length under which points coincide; ``left``
    0 or 1 when that leg is known to be the character's left (None: the joints decide)."""
    up = np.asarray(up, dtype=np.float64)
    hips, ankles = np.asarray(hips, dtype=np.float64), np.asarray(ankles, dtype=np.float64)
    knee_pair = [] if knees is None else [tuple(np.asarray(knees, dtype=np.float64))]
    lat = lateral(up, [tuple(hips), *knee_pair, tuple(ankles)], tiny)
    lengths = [float(np.linalg.norm(hips[k] - ankles[k])) or 1.0 for k in (0, 1)]
    toes = [_toes(up, ankles[k], below[k], lengths[k]) for k in (0, 1)]
    if lat is None:
        sign, clear, side = 0, False, None
    else:
        side = np.cross(up, lat)
        if left is None:
            sign, clear = _votes(up, side, hips, ankles, knees, feet, toes, lengths, tiny)
        else:
            sign, clear = (-1 if left == 0 else 1), True  # left = up x forward: leg 0 (at +lat) left when sign < 0
    ahead = [t for t in toes if t is not None]
    ahead = np.mean(ahead, axis=0) if ahead else np.zeros(3)
    size = float(np.linalg.norm(ahead))
    if sign == 0:
        forward = ahead / size if size > tiny else None
    else:
        forward = sign * side
        if size > tiny and float(ahead @ forward) > _TOES_AHEAD * size:
            forward = ahead / size
    return Facing(lat, sign, clear, forward)


def _toes(up, ankle, below, length):
    """Offset across up from the ankle to the farthest joint below the foot, or None when the foot has no joint
    at least _TOE_REACH leg lengths away."""
    below = np.asarray(below, dtype=np.float64).reshape(-1, 3)
    if not len(below):
        return None
    offsets = across(up, below - ankle)
    reach = np.linalg.norm(offsets, axis=1)
    k = int(np.argmax(reach))
    return offsets[k] if reach[k] >= _TOE_REACH * length else None


def _votes(up, side, hips, ankles, knees, feet, toes, lengths, tiny):
    """(sign, clear) of the joints' votes for the side the body faces (module docstring)."""
    cos = [None if t is None else float(t @ side) / float(np.linalg.norm(t)) for t in toes]
    if all(c is not None and abs(c) > _TOE_CLEAR for c in cos) and np.sign(cos[0]) == np.sign(cos[1]):
        return int(np.sign(cos[0])), True
    bends = [] if knees is None else [_knee(side, hips[k], knees[k], ankles[k], lengths[k], tiny) for k in (0, 1)]
    flats = [None if feet is None or feet[k] is None else _foot(up, side, feet[k], tiny) for k in (0, 1)]
    knee_signs = {int(np.sign(b)) for b in bends if abs(b) > _KNEE_BEND}
    foot_signs = {int(np.sign(f)) for f in flats if f is not None and abs(f) > _TOE_CLEAR}
    if (bends and len(knee_signs) == 1 and all(abs(b) > _KNEE_BEND for b in bends) and foot_signs == knee_signs
            and all(f is not None and abs(f) > _TOE_CLEAR for f in flats)):
        return knee_signs.pop(), True
    votes = sum(np.sign(c) for c in cos if c is not None and abs(c) > _TOE_CLEAR)
    votes += sum(np.sign(b) for b in bends if abs(b) > _KNEE_BEND)
    votes += 0.5 * sum(np.sign(f) for f in flats if f is not None and abs(f) > _TOE_CLEAR)
    return int(np.sign(votes)), False


def _knee(side, hip, knee, ankle, length, tiny):
    """Signed offset of the knee from the hip - ankle line along side, in leg lengths."""
    line = ankle - hip
    t = float((knee - hip) @ line) / max(float(line @ line), tiny ** 2)
    return float((knee - (hip + t * line)) @ side) / length


def _foot(up, side, direction, tiny):
    """Cosine between side and the foot bone's direction across up, or None when it points mostly along up."""
    direction = np.asarray(direction, dtype=np.float64)
    flat = across(up, direction)
    if np.linalg.norm(flat) < _FOOT_FLAT * max(float(np.linalg.norm(direction)), tiny):
        return None
    return float(flat @ side) / float(np.linalg.norm(flat))
