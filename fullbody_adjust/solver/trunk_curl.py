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

import numpy as np

from .geometry import any_perpendicular, any_set, cross, dot, norm, rotate_about_axis, swing_rotation

# Secant steps on the bend angle (the end's direction, then the chord): both are smooth in the angle and the
# first guess is close, so a few steps leave far less than the chain tolerance; they stop once every row is
# within _SETTLED (radians, or that fraction of the distance).
_STEPS = 8
_SETTLED = 1e-12


def _segment_turns(shares, segments):
    """(b,m) how many joint angles each segment turns by: the sum of the shares of the joints below it."""
    return np.cumsum(np.broadcast_to(shares, segments.shape[:2]), axis=1)


def _segments_bent(segments, axis, alpha, shares):
    """Segments (b,m,3) with joint i turned by shares[..., i] * alpha (b,) about axis (b,3)."""
    angles = alpha[:, None] * _segment_turns(shares, segments)
    return rotate_about_axis(segments, np.broadcast_to(axis[:, None, :], segments.shape), angles)


def _bend_axis(chains, targets):
    """(b,3) unit axis normal to base->end and base->target (the plane the spine curls in); where the two are
    parallel, normal to the spine's own curve, else any perpendicular of base->end."""
    end = chains[:, -1] - chains[:, 0]
    axis = cross(end, targets - chains[:, 0])
    own = cross(chains[:, 1] - chains[:, 0], chains[:, -1] - chains[:, -2])
    scale = norm(end) * norm(end)
    axis = np.where((norm(axis) > 1e-9 * scale)[:, None], axis,
                    np.where((norm(own) > 1e-9 * scale)[:, None], own, any_perpendicular(end)))
    return axis / norm(axis)[:, None]


def _secant(f, goal, a0, a1, settled):
    """Secant steps on f(alpha) = goal from a0, a1 (b,); f returns (b,). A row stops once it is within `settled`
    (so its result does not depend on the other rows). Returns the last alpha."""
    f0, f1 = f(a0), f(a1)
    for _ in range(_STEPS):
        moving = np.abs(f1 - goal) > settled
        if not any_set(moving):
            break
        slope = f1 - f0
        ok = moving & (np.abs(slope) > 1e-15)
        a2 = np.where(ok, a1 - (f1 - goal) * (a1 - a0) / np.where(ok, slope, 1.0), a1)
        a0, f0, a1 = np.where(ok, a1, a0), np.where(ok, f1, f0), a2
        f1 = f(a1)
    return a1


def _pointing_alpha(chains, targets, axis, shares):
    """(b,) the joint angle of the curl about `axis` that points the end from the base toward `targets`."""
    segments = np.diff(chains, axis=1)
    end0 = chains[:, -1] - chains[:, 0]
    to_target = targets - chains[:, 0]
    phi = np.arctan2(dot(axis, cross(end0, to_target)), dot(end0, to_target))

    def turned(alpha):
        end = _segments_bent(segments, axis, alpha, shares).sum(axis=1)
        return np.arctan2(dot(axis, cross(end0, end)), dot(end0, end))

    # The end turns by about the mean of the segments' turns: start from that and from no bend.
    return _secant(turned, phi, np.zeros_like(phi), phi / np.mean(_segment_turns(shares, segments), axis=1),
                   _SETTLED)


def curl_chord(chains, targets, shares):
    """(b,) distance from the base to the end of the chains (b,n,3) curled to point at `targets` (b,3), joint i
    bending by shares[..., i] (m,) or (b,m) of the curl's angle."""
    axis = _bend_axis(chains, targets)
    alpha = _pointing_alpha(chains, targets, axis, shares)
    return norm(_segments_bent(np.diff(chains, axis=1), axis, alpha, shares).sum(axis=1))


def curl_start(chains, targets, shares):
    """Chains (b,n,3) curled so their end lies at `targets` (b,3), the base fixed: the joint angle sets the
    chord to the target's distance (from the angle that points the end at it), then the whole chain turns
    about the base onto it. A target beyond the chord any angle gives gets the closest one."""
    base = chains[:, 0]
    segments = np.diff(chains, axis=1)
    axis = _bend_axis(chains, targets)
    pointing = _pointing_alpha(chains, targets, axis, shares)
    distance = norm(targets - base)
    chord = (lambda alpha: norm(_segments_bent(segments, axis, alpha, shares).sum(axis=1)))
    alpha = _secant(chord, distance, pointing, pointing * (1.0 + 1e-3) + 1e-6, _SETTLED * distance)
    # Beyond every chord the secant wanders off: the pointing curl is then as close as it gets.
    better = np.isfinite(alpha) & (np.abs(chord(np.where(np.isfinite(alpha), alpha, 0.0)) - distance)
                                   < np.abs(chord(pointing) - distance))
    alpha = np.where(better, alpha, pointing)
    bent = _segments_bent(segments, axis, alpha, shares)
    turn = swing_rotation(bent.sum(axis=1), targets - base)
    out = chains.copy()
    out[:, 1:] = base[:, None, :] + np.cumsum(np.einsum("bij,bkj->bki", turn, bent), axis=1)
    return out
