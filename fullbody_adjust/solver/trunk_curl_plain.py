"""trunk_curl.curl_chord for a few trunks in plain Python floats (the lean of one frame's SC asks for it a few times
a solve): the numpy path's operations in its order (a sum over segments from the first), the trigonometry numpy's
own routines on one value (geometry_plain.py), so each row gets the numpy path's bits
(tests/solver/test_trunk_curl_plain.py). The secant steps stop per row as there: a row's steps never depend on
the others. Where plain floats would divide by zero, the numpy path answers."""

import operator
from functools import reduce
from itertools import accumulate

import numpy as np

from . import geometry_plain as g
from . import trunk_curl
from .trunk_curl import _SETTLED, _STEPS

# Up to this many trunks, plain floats.
_FEW_CHAINS = 4


def curl_chord(chains, targets, shares):
    """trunk_curl.curl_chord(chains (b,n,3), targets (b,3), shares (m,) or (b,m)): (b,), in plain floats for a
    few rows."""
    if len(chains) <= _FEW_CHAINS:
        share_rows = np.broadcast_to(shares, (chains.shape[0], chains.shape[1] - 1)).tolist()
        try:
            return np.array([_chord(c, t, s) for c, t, s in zip(chains.tolist(), targets.tolist(), share_rows)],
                            dtype=np.float64)
        except ZeroDivisionError:
            pass
    return trunk_curl.curl_chord(chains, targets, shares)


def _chord(chain, target, shares):
    segments = [g.sub(chain[i + 1], chain[i]) for i in range(len(chain) - 1)]
    turns = list(accumulate(shares))  # numpy's cumsum: from the first, in order
    axis = _bend_axis(chain, target)
    alpha = _pointing_alpha(chain, target, segments, axis, turns)
    return g.norm(reduce(g.add, _bent(segments, axis, alpha, turns)))


def _bent(segments, axis, alpha, turns):
    return [g.rotate_about_axis(s, axis, alpha * t) for s, t in zip(segments, turns)]


def _bend_axis(chain, target):
    end = g.sub(chain[-1], chain[0])
    axis = g.cross(end, g.sub(target, chain[0]))
    scale = g.norm(end) * g.norm(end)
    if not g.norm(axis) > 1e-9 * scale:
        own = g.cross(g.sub(chain[1], chain[0]), g.sub(chain[-1], chain[-2]))
        axis = own if g.norm(own) > 1e-9 * scale else g.any_perpendicular(end)
    return g.divided_by_norm(axis)


def _pointing_alpha(chain, target, segments, axis, turns):
    end0 = g.sub(chain[-1], chain[0])
    to_target = g.sub(target, chain[0])

    def turned(alpha):
        end = reduce(g.add, _bent(segments, axis, alpha, turns))
        return float(np.arctan2(g.dot(axis, g.cross(end0, end)), g.dot(end0, end)))

    phi = float(np.arctan2(g.dot(axis, g.cross(end0, to_target)), g.dot(end0, to_target)))
    return _secant(turned, phi, 0.0, phi / (reduce(operator.add, turns) / len(turns)), _SETTLED)


def _secant(f, goal, a0, a1, settled):
    f0, f1 = f(a0), f(a1)
    for _ in range(_STEPS):
        slope = f1 - f0
        if not (abs(f1 - goal) > settled and abs(slope) > 1e-15):
            break  # settled, or stuck: the numpy path leaves this row's values as they are from here on
        a0, f0, a1 = a1, f1, a1 - (f1 - goal) * (a1 - a0) / slope
        f1 = f(a1)
    return a1
