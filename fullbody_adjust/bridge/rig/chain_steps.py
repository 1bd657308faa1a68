"""The steps that place a two-bone IK chain through its controls (control_match): its bend (the turn of its
middle joint about the chain's axis) and its scale (its length), taken from the chain as the rig evaluates it or as
chain_prediction predicts it. Plain floats on nested lists: with numpy's per-call cost on each 4x4 matrix and
3-vector, these took half the matching's time outside Blender's evaluations."""

import math

import numpy as np

from ...solver.maths import vectors as g

# A scale step is taken against the slope its last step measured when that step moved the control's scale by
# more than this (in logs; float32 channels); under _SLOPE_MIN the control no longer sets the chain's length.
_SLOPE_STEP = 1e-5
_SLOPE_MIN = 0.2


def matrix(pose_bone):
    return np.array(pose_bone.matrix, dtype=np.float64)


def unconstrained(pose_bone):
    """``pose_bone``'s armature-space matrix before its constraints (an IK's, a damped track's): its parent's
    evaluated matrix, its rest relation to it and its channels (a plain parent: what Rigify's IK swing and IK base
    have)."""
    parent = pose_bone.parent
    relation = parent.bone.matrix_local.inverted() @ pose_bone.bone.matrix_local @ pose_bone.matrix_basis
    return matrix(parent) @ np.array(relation, dtype=np.float64)


def head(m):
    """A bone's head from its 4x4 matrix ``m`` as nested lists. Plain floats: with numpy's per-call cost on each
    4x4 matrix, these errors took half the matching's time outside Blender's evaluations."""
    return (m[0][3], m[1][3], m[2][3])


def tail(m, length):
    """A bone's tail (the chain's middle joint for a chain's first bone): head + length * its Y axis."""
    return (m[0][1] * length + m[0][3], m[1][1] * length + m[1][3], m[2][1] * length + m[2][3])


def chain_of(pose_bones, pair, lengths, predicted=None, samples=()):
    """(first bone's matrix, end bone's head, chain length) of a bend or scale pair's chain as nested lists: as
    evaluated, or as ``predicted`` (chain_prediction.predicted_chain), its length then the one the chain's stretch
    ``samples`` (record_stretch) give at its predicted end's distance (modelled_length), or without them the
    evaluated one. None for a rigid pair."""
    if pair.kind == "rigid":
        return None
    bone, end = matrix(pose_bones[pair.bone]).tolist(), head(matrix(pose_bones[pair.end]).tolist())
    length = chain_length(bone, end, lengths[pair.bone])
    if predicted is not None:
        bone, end = predicted[1].tolist(), tuple(predicted[2].tolist())
        modelled = modelled_length(samples, math.dist(head(bone), end), pose_bones[pair.control].scale[1],
                                   lengths[pair.bone])
        length = length if modelled is None else modelled
    return bone, end, length


def _bend_plane(chain, pair, desired, lengths):
    """(base, axis, now, want) of a bend pair: the chain's first joint, its unit axis (to the end bone's head)
    and the evaluated (or predicted: ``chain``, chain_of) and desired middle joints' offsets from that axis, or None
    when the axis or either offset is degenerate (a straight chain has no bend plane to turn). Plain floats
    (numpy's per-call cost on 3-vectors made a bend step cost 0.15 ms)."""
    length = lengths[pair.bone]
    bone, end, _length = chain
    base = head(bone)
    axis = g.sub(end, base)
    size = g.norm(axis)
    if size <= 1e-9 * length:
        return None
    axis = g.divided(axis, size)
    now = g.sub(tail(bone, length), base)
    want = g.sub(tail(desired[pair.bone].tolist(), length), base)
    now = g.sub(now, g.scaled(axis, g.dot(now, axis)))
    want = g.sub(want, g.scaled(axis, g.dot(want, axis)))
    if min(g.norm(now), g.norm(want)) <= 1e-9 * length:
        return None
    return base, axis, now, want


def _bend_angle(plane):
    _base, axis, now, want = plane
    return math.atan2(g.dot(g.cross(now, want), axis), g.dot(now, want))


def bend_error(chain, pair, desired, lengths):
    """How far a bend pair's middle joint is turned from the desired one about the chain's axis: the arc at the
    desired joint's distance from the axis (what a bend step removes). Its distance from the axis and along
    it are not the bend's: a stretchy IK (Rigify's) shares its stretch between its two bones as its solver
    finds, and no control sets that share (the first bone's scale is the scale pair's)."""
    plane = _bend_plane(chain, pair, desired, lengths)
    return 0.0 if plane is None else abs(_bend_angle(plane)) * g.norm(plane[3])


def bend_step(chain, pair, desired, lengths):
    """The rotation (4x4, about the chain's axis through its first joint) taking the evaluated (or predicted)
    middle joint towards the desired one, or None when the axis is degenerate."""
    plane = _bend_plane(chain, pair, desired, lengths)
    if plane is None:
        return None
    base, axis = plane[0], plane[1]
    turn = g.rotation_about(axis, _bend_angle(plane))  # about the base: x -> R (x - base) + base
    shift = [b - g.dot(row, base) for row, b in zip(turn, base)]
    return np.array([[*turn[0], shift[0]], [*turn[1], shift[1]], [*turn[2], shift[2]], [0.0, 0.0, 0.0, 1.0]])


def chain_length(bone, end, length):
    """A two-bone chain's length from its first bone's matrix ``bone`` (its head, and its tail: the middle joint)
    and its end bone's head ``end``, as nested lists."""
    middle = tail(bone, length)
    return math.dist(head(bone), middle) + math.dist(middle, end)


def _scale_lengths(chain, pair, desired, lengths):
    """A scale pair's chain length (chain_length) as evaluated (or predicted: ``chain``, chain_of) and as desired."""
    return chain[2], chain_length(desired[pair.bone].tolist(), head(desired[pair.end].tolist()), lengths[pair.bone])


# Stretch samples closer than this (in the chain's first bone's lengths) give no slope: Blender's float32 IK.
_SAMPLE_APART = 1e-3
# How many stretch samples a chain keeps (record_stretch): the farthest from the newest go first.
_SAMPLES = 64


def record_stretch(samples, chain, scale, length, miss=0.0):
    """Keep in ``samples`` (a list sorted by x, at most _SAMPLES) where the evaluated ``chain`` stands: (x, l, m), its
    end's distance from its base, its length and ``miss`` (how far its end lies beyond its end control, along the
    chain's axis) over ``scale`` (its base control's) times ``length`` (its first bone's), replacing a sample within
    _SAMPLE_APART of it. A stretchy IK's l is a function of x alone (scale_step): measured on the generated basic
    rig, the same to 1e-4 (0.03 mm on its arm) across target directions, base scales and bends (Blender's legacy IK
    starts each evaluation from the base control's channels, which control_match only turns about the chain's axis,
    a symmetry of the solve), from a 2.7 % shrink at half reach to 0.2 % stretch at 0.99; smooth but curved (its
    slope in x from 0.09 to 0.2 between 0.75 and 0.95 of full reach), so that a step is modelled from the samples
    about it, not the last two. So is m (the IK's own miss: 0.003 mm at 0.75 of full reach, 0.033 mm at 0.95, 0.12
    mm straight, the same to 0.0004 mm across directions and bends; off the axis under 0.001 mm)."""
    bone, end, now = chain
    x = math.dist(head(bone), end) / (scale * length)
    sample = (x, now / (scale * length), miss / (scale * length))
    near = [i for i, other in enumerate(samples) if abs(other[0] - x) < _SAMPLE_APART]
    for i in reversed(near):
        del samples[i]
    samples.append(sample)
    samples.sort()
    while len(samples) > _SAMPLES:
        samples.remove(max(samples, key=lambda s: abs(s[0] - x)))


def record(pose_bones, pair, chain, lengths, samples, end=None):
    """record_stretch of scale pair ``pair``'s evaluated ``chain``, its miss measured from its end control's pair
    ``end`` (None: 0)."""
    miss = 0.0 if end is None else axial_miss(chain, head(matrix(pose_bones[end.control]).tolist()))
    record_stretch(samples, chain, pose_bones[pair.control].scale[1], lengths[pair.bone], miss)


def axial_miss(chain, control_head):
    """How far the evaluated ``chain``'s end (chain_of) lies beyond its end control's head ``control_head``
    along the chain's axis (its IK's own miss; negative: short of it)."""
    bone, end, _length = chain
    base = head(bone)
    axis = g.sub(end, base)
    size = g.norm(axis)
    return 0.0 if size <= 0.0 else g.dot(g.sub(end, control_head), axis) / size


def _at(samples, x, k):
    """Component ``k`` of the ``samples`` (record_stretch) at ``x``: a parabola through the three nearest, a line
    through two, a constant with one."""
    near = sorted(samples, key=lambda s: abs(s[0] - x))[:3]
    xs = [s[0] for s in near]
    apart = all(abs(a - b) >= _SAMPLE_APART for i, a in enumerate(xs) for b in xs[i + 1:])
    if len(near) == 1 or not apart:
        return near[0][k]
    value = 0.0
    for c in np.polyfit(xs, [s[k] for s in near], len(near) - 1).tolist():
        value = value * x + c
    return value


def modelled_length(samples, distance, scale, length):
    """The chain length a stretchy IK gives with its end ``distance`` from its base and its base control's
    ``scale`` (the first bone's rest ``length``): s c l(d / (s c)), l from the ``samples`` nearest that x (_at);
    None without samples."""
    if not samples or scale <= 0.0:
        return None
    return scale * length * _at(samples, distance / (scale * length), 1)


def modelled_miss(samples, distance, scale, length):
    """How far the chain's end lies beyond its end control along its axis (record_stretch's m), as
    modelled_length; None without samples."""
    if not samples or scale <= 0.0:
        return None
    return scale * length * _at(samples, distance / (scale * length), 2)


def _about(samples, ratio):
    """The two ``samples`` (sorted by x) whose l / x brackets ``ratio`` (a stretchy chain's l / x falls as x
    grows), or the two at the nearer end of them; one sample when there is only one."""
    if len(samples) < 2:
        return samples[:]
    for a, b in zip(samples, samples[1:]):
        if b[1] / b[0] <= ratio <= a[1] / a[0]:
            return [a, b]
    return samples[:2] if ratio > samples[0][1] / samples[0][0] else samples[-2:]


def _modelled_scale(samples, chain, want, length):
    """The base control's scale s that gives the chain the length ``want`` with its end where ``chain`` has it:
    L = s c l(d / (s c)) (c: the first bone's length, d: the end's distance), so l(x) / x = L / d, with l(x)
    linear through the two ``samples`` (record_stretch) about that ratio (constant with one). None where the
    chain's length no longer follows s (its slope in logs, 1 - x l'(x) / l, under _SLOPE_MIN: near full
    stretch) or without samples."""
    if not samples:
        return None
    bone, end, _now = chain
    distance = math.dist(head(bone), end)
    if distance <= 0.0:
        return None
    pair = _about(samples, want / distance)
    x1, l1 = pair[-1][:2]
    slope = 0.0
    if len(pair) > 1 and abs(x1 - pair[0][0]) >= _SAMPLE_APART:
        slope = (l1 - pair[0][1]) / (x1 - pair[0][0])
    if 1.0 - slope * x1 / l1 < _SLOPE_MIN:
        return None
    scale = (want / length - slope * distance / length) / (l1 - slope * x1)
    if scale <= 0.0:
        return None
    curved = _curved_scale(samples, distance / (scale * length), want / distance, length, distance)
    return scale if curved is None else curved


def _curved_scale(samples, x, ratio, length, distance):
    """_modelled_scale's s with l(x) the parabola through the three ``samples`` nearest its linear model's ``x``
    (l / x = ``ratio`` solved by Newton's method from ``x``): the curve's bend left a secant's length 0.16 mm off
    over 0.1 of x (a generated rig's arm at 0.8 of its reach). None with fewer samples, or where the parabola
    gives no root near ``x`` or the control no longer sets the length there (_SLOPE_MIN)."""
    if len(samples) < 3:
        return None
    near = sorted(samples, key=lambda s: abs(s[0] - x))[:3]
    xs = [s[0] for s in near]
    if min(abs(a - b) for a, b in ((xs[0], xs[1]), (xs[0], xs[2]), (xs[1], xs[2]))) < _SAMPLE_APART:
        return None
    c, b, a = np.polyfit(xs, [s[1] for s in near], 2).tolist()
    root = x
    for _ in range(8):  # f(x) = l(x) - ratio x
        f, df = a + b * root + c * root * root - ratio * root, b + 2.0 * c * root - ratio
        if df >= 0.0:
            return None  # l / x no longer falls as x grows: past what the control sets
        root -= f / df
    l, dl = a + b * root + c * root * root, b + 2.0 * c * root
    if abs(root - x) > 0.5 * x or root <= 0.0 or 1.0 - root * dl / l < _SLOPE_MIN:
        return None
    return distance / (root * length)


# The least slope (in logs) a first scale step is taken against (_local_slope): 20 times the ratio at most.
_LOCAL_SLOPE_MIN = 0.05


def _local_slope(samples, chain, length, scale):
    """How much of a scaling of the base control reaches the chain's length (in logs: 1 - x l'(x) / l) at the
    chain's x, from the line through the two ``samples`` nearest it (record_stretch); None with fewer, or with
    those two closer than _SAMPLE_APART."""
    if len(samples) < 2:
        return None
    bone, end, _now = chain
    x = math.dist(head(bone), end) / (scale * length)
    a, b = sorted(samples, key=lambda s: abs(s[0] - x))[:2]
    if abs(a[0] - b[0]) < _SAMPLE_APART:
        return None
    slope = (b[1] - a[1]) / (b[0] - a[0])
    return 1.0 - slope * x / (a[1] + slope * (x - a[0]))


def scale_step(pair, control, chain, desired, lengths, scaled, predicted=False, samples=()):
    """A scale pair's new control scale (3,): its current one times the chain's desired over its evaluated length,
    that ratio raised to 1 / the slope the last step measured (how much of a control's scaling reached the chain,
    in logs: a stretchy IK undoes part of it, on Rigify's limbs about two thirds, which left 0.65 of the error
    after each step), at most 1. None once a step measured a slope under _SLOPE_MIN: near full stretch the IK
    stretches the chain to its end whatever its base's scale (a straight arm's length stayed 0.1 mm long over
    six sweeps, the control's scaling reaching it less each time), and the control is left as it is.
    ``scaled`` keeps each pair's last step (None: left); a step from a ``predicted`` chain is not kept: its length
    is not one the control's scale was measured to give. With ``samples`` of the chain's stretch (record_stretch),
    the scale is the one they model (_modelled_scale): a drag's last update's samples predict the next one's."""
    last = scaled.get(pair, ())
    if last is None:
        return None
    now, want = _scale_lengths(chain, pair, desired, lengths)
    current = np.array(control.scale, dtype=np.float64)
    modelled = _modelled_scale(samples, chain, want, lengths[pair.bone])
    if modelled is not None:
        return current * (modelled / current[1])
    ratio = math.log(want / now)
    local = _local_slope(samples, chain, lengths[pair.bone], current[1])
    if local is not None and not last:
        # The first step of a placement, against the slope its samples show (near full reach, where the model
        # gives up, 0.2 or less: stepped by the plain ratio, a straight arm's length crept 0.18 -> 0.11 mm over
        # five Live updates, an evaluation each); at least _LOCAL_SLOPE_MIN.
        ratio /= min(max(local, _LOCAL_SLOPE_MIN), 1.0)
    if not predicted:
        scaled[pair] = (current[1], now)
    if last:
        moved = math.log(current[1] / last[0])
        if abs(moved) > _SLOPE_STEP:
            slope = math.log(now / last[1]) / moved
            if slope < _SLOPE_MIN:
                scaled[pair] = None
                return None
            ratio /= min(slope, 1.0)
    return current * math.exp(ratio)


def chain_error(chain, pair, desired, lengths):
    """A bend pair's turn (bend_error) or a scale pair's chain length error, from ``chain`` (chain)."""
    if pair.kind == "bend":
        return bend_error(chain, pair, desired, lengths)
    now, want = _scale_lengths(chain, pair, desired, lengths)
    return abs(now - want)
