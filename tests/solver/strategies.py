"""Hypothesis strategies for solver tests: chains, targets, boxes, limits.

Numbers are drawn through hypothesis (not from a seeded RNG) so failures shrink to small examples.
"""

import numpy as np
from hypothesis import assume
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from fullbody_adjust.solver.chain.settings import _reach_bounds

coords = st.floats(-2.0, 2.0, allow_nan=False, allow_infinity=False)


@st.composite
def unit_vectors(draw):
    v = draw(arrays(np.float64, 3, elements=st.floats(-1.0, 1.0)))
    n = float(np.linalg.norm(v))
    if n < 1e-3:  # hypothesis likes zeros: any fixed direction is as good as another
        return np.array([0.0, 0.0, 1.0])
    return v / n


@st.composite
def chains(draw, min_joints=2, max_joints=8, min_length=0.5, max_length=1.5):
    """Joint positions (n,3) of a random chain with segment lengths in [min_length, max_length]."""
    n = draw(st.integers(min_joints, max_joints))
    lengths = draw(arrays(np.float64, n - 1, elements=st.floats(min_length, max_length)))
    dirs = np.array([draw(unit_vectors()) for _ in range(n - 1)])
    base = draw(arrays(np.float64, 3, elements=coords))
    return np.vstack([base, base + np.cumsum(dirs * lengths[:, None], axis=0)])


def lengths_of(p):
    return np.linalg.norm(np.diff(p, axis=0), axis=1)


@st.composite
def reachable_targets(draw, positions, margin=0.1, near=0.25):
    """A target whose distance from the base lies well inside the reachable shell:
    [max(inner + margin*total, near*total), (1-margin)*total]. FABRIK converges slowly (thousands of
    iterations) right at the shell's borders and for targets folded close to the base."""
    total, inner = (float(x) for x in _reach_bounds(lengths_of(positions)))
    lo, hi = max(inner + margin * total, near * total), (1.0 - margin) * total
    dist = draw(st.floats(lo, hi)) if hi > lo else 0.5 * (lo + hi)
    return positions[0] + dist * draw(unit_vectors())


@st.composite
def well_conditioned_targets(draw, positions, max_bend=np.pi / 2, near=0.25, far=0.9):
    """A target FABRIK is known to meet within a few hundred iterations: the end of another pose of the same
    chain whose every joint bends at most `max_bend`, at a distance in [near, far] * reach from the base.
    (Targets that need a joint folded nearly flat, or that lie at the reach's borders, can take FABRIK many
    thousands of iterations; that is the method, not this implementation.)"""
    lengths = lengths_of(positions)
    total = float(lengths.sum())
    d = draw(unit_vectors())
    end = positions[0] + lengths[0] * d
    for length in lengths[1:]:
        w = draw(unit_vectors())
        p = w - np.dot(w, d) * d
        if np.linalg.norm(p) < 1e-6:
            p = np.cross(d, [1.0, 0.0, 0.0] if abs(d[0]) < 0.9 else [0.0, 1.0, 0.0])
        p /= np.linalg.norm(p)
        bend = draw(st.floats(0.0, max_bend))
        d = np.cos(bend) * d + np.sin(bend) * p
        end = end + length * d
    assume(near * total <= np.linalg.norm(end - positions[0]) <= far * total)
    return end


@st.composite
def unreachable_targets(draw, positions):
    total = float(lengths_of(positions).sum())
    dist = draw(st.floats(1.05 * total, 3.0 * total))
    return positions[0] + dist * draw(unit_vectors())


@st.composite
def boxes_corners(draw, min_boxes=0, max_boxes=4, lo=-4.0, hi=4.0, min_size=0.05, max_size=1.5):
    """(K,2,3) min/max corner pairs."""
    k = draw(st.integers(min_boxes, max_boxes))
    mins = draw(arrays(np.float64, (k, 3), elements=st.floats(lo, hi)))
    sizes = draw(arrays(np.float64, (k, 3), elements=st.floats(min_size, max_size)))
    return np.stack([mins, mins + sizes], axis=1)
