"""The trunk's curl: the spine bent about one axis, each joint by its share of one angle (SubBasePlacement.
_curl_shares), whose chord sets how far from the trunk's base the SC goes when the trunk leans
(SubBasePlacement._place_sc), and the shape the trunk's chain solve then starts from (SubBasePlacement._sub_bases).

FABRIK from the start pose settles a small SC move by whichever spine joints its passes reach first, and where
a joint's limit binds it hands its share to the next one: from one frame to the next the bend then jumps
between joints although the SC's target moves smoothly. A nearly straight spine that must also shorten can only
buckle (a few millimetres shorter is centimetres sideways). The curl is a smooth function of the SC's target:
the lean puts the SC at the chord of the curl that points it there, and the chain solve starts from that curl,
which already meets the target, so it has only the joint limits and the obstacles left to settle.
"""

from functools import reduce

import numpy as np

from ..maths import lanes
from ..maths import vectors as vec

# Secant steps on the bend angle (the end's direction, then the chord): both are smooth in the angle and the
# first guess is close, so a few steps leave far less than the chain tolerance; they stop once every row is
# within _SETTLED (radians, or that fraction of the distance).
_STEPS = 8
_SETTLED = 1e-12


def curl_chord(chains, targets, shares):
    """(b,) distance from the base to the end of the chains (b,n,3) curled to point at `targets` (b,3), joint i
    bending by shares[..., i] (m,) or (b,m) of the curl's angle."""
    return lanes.run(_chord, (chains, targets), values=(_rows(shares, chains),))


def curl_start(chains, targets, shares):
    """Chains (b,n,3) curled so their end lies at `targets` (b,3), the base fixed: the joint angle sets the
    chord to the target's distance (from the angle that points the end at it), then the whole chain turns
    about the base onto it. A target beyond the chord any angle gives gets the closest one."""
    return lanes.run(_start, (chains, targets), values=(_rows(shares, chains),))


def _rows(shares, chains):
    return np.ascontiguousarray(np.broadcast_to(shares, (chains.shape[0], chains.shape[1] - 1)), dtype=np.float64)


def _chord(chain, target, shares):
    segments, turns = _segments_and_turns(chain, shares)
    axis = _bend_axis(chain, target)
    alpha = _pointing_alpha(chain, target, segments, axis, turns)
    return vec.norm(_bent_end(segments, axis, alpha, turns))


def _start(chain, target, shares):
    base = chain[0]
    segments, turns = _segments_and_turns(chain, shares)
    axis = _bend_axis(chain, target)
    pointing = _pointing_alpha(chain, target, segments, axis, turns)
    distance = vec.norm(vec.sub(target, base))
    chord = (lambda alpha: vec.norm(_bent_end(segments, axis, alpha, turns)))
    alpha = _secant(chord, distance, pointing, pointing * (1.0 + 1e-3) + 1e-6, _SETTLED * distance)
    # Beyond every chord the secant wanders off: the pointing curl is then as close as it gets.
    finite = lanes.isfinite(alpha)
    better = finite & (abs(chord(lanes.where(finite, alpha, 0.0)) - distance) < abs(chord(pointing) - distance))
    alpha = lanes.where(better, alpha, pointing)
    bent = _bent(segments, axis, alpha, turns)
    turn = vec.swing_rotation(reduce(vec.add, bent), vec.sub(target, base))
    out, at = [base], (0.0, 0.0, 0.0)
    for s in bent:
        at = vec.add(at, vec.apply_matrix(turn, s))
        out.append(vec.add(base, at))
    return out


def _segments_and_turns(chain, shares):
    """The chain's segments, and how many joint angles each turns by: the sum of the shares of the joints below
    it (in order, from the first)."""
    turns = [shares[0]]
    for s in shares[1:]:
        turns.append(turns[-1] + s)
    return [vec.sub(chain[i + 1], chain[i]) for i in range(len(chain) - 1)], turns


def _bent(segments, axis, alpha, turns):
    """The segments with joint i turned by its share of alpha about axis."""
    return [vec.rotate_about_axis(s, axis, alpha * t) for s, t in zip(segments, turns)]


def _bent_end(segments, axis, alpha, turns):
    return reduce(vec.add, _bent(segments, axis, alpha, turns))


def _bend_axis(chain, target):
    """Unit axis normal to base->end and base->target (the plane the spine curls in); where the two are
    parallel, normal to the spine's own curve, else any perpendicular of base->end."""
    end = vec.sub(chain[-1], chain[0])
    axis = vec.cross(end, vec.sub(target, chain[0]))
    scale = vec.norm(end) * vec.norm(end)
    weak = lanes.not_(vec.norm(axis) > 1e-9 * scale)
    if lanes.any_(weak):
        own = vec.cross(vec.sub(chain[1], chain[0]), vec.sub(chain[-1], chain[-2]))
        fallback = lanes.pick(vec.norm(own) > 1e-9 * scale, own, vec.any_perpendicular(end))
        axis = lanes.pick(weak, fallback, axis)
    return vec.divided(axis, vec.norm(axis))


def _pointing_alpha(chain, target, segments, axis, turns):
    """The joint angle of the curl about `axis` that points the end from the base toward `target`."""
    end0 = vec.sub(chain[-1], chain[0])
    to_target = vec.sub(target, chain[0])

    def turned(alpha):
        end = _bent_end(segments, axis, alpha, turns)
        return lanes.arctan2(vec.dot(axis, vec.cross(end0, end)), vec.dot(end0, end))

    phi = lanes.arctan2(vec.dot(axis, vec.cross(end0, to_target)), vec.dot(end0, to_target))
    # The end turns by about the mean of the segments' turns: start from that and from no bend.
    return _secant(turned, phi, 0.0, lanes.divide(phi, reduce(lambda a, b: a + b, turns) / len(turns)),
                   _SETTLED)


def _secant(f, goal, a0, a1, settled):
    """Secant steps on f(alpha) = goal from a0, a1. A lane stops once it is within `settled` (so its result does
    not depend on the other lanes). Returns the last alpha."""
    f0, f1 = f(a0), f(a1)
    for _ in range(_STEPS):
        slope = f1 - f0
        ok = (abs(f1 - goal) > settled) & (abs(slope) > 1e-15)
        if not lanes.any_(ok):
            break  # settled, or stuck
        a2 = lanes.where(ok, a1 - (f1 - goal) * (a1 - a0) / lanes.where(ok, slope, 1.0), a1)
        a0, f0, a1 = lanes.where(ok, a1, a0), lanes.where(ok, f1, f0), a2
        f1 = f(a1)
    return a1
