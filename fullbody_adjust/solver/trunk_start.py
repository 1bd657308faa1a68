"""Warm start of the trunk before its chain solve: the spine bent evenly, then turned, so that its end is at the
new SC (see adjust._Problem._solve).

FABRIK started from the same pose for every frame settles a spine's bend among its joints differently from one
target to the next (it stops wherever the tolerance is first met), so over frames whose SC moves smoothly the
bend can jump between joints. This start is a smooth function of the SC target: every joint adds the same bend
angle about one axis (the chain's shape otherwise kept) until the end is at the target's distance from the base,
then the whole chain turns about the base onto the target. FABRIK then only corrects limits and obstacles."""

import numpy as np

from .geometry import any_perpendicular, apply_matrix, cross, norm, rotate_about_axis, swing_rotation

# Bend angles tried per joint (radians): the first crossing of the target's distance is refined.
_GRID = np.linspace(0.0, np.pi / 2, 91)
_REFINE = 30
# A chain counts as curved when its joints turn by more than about this much in all (radians).
_CURVED = 0.05


def trunk_start(start, targets):
    """Chains (b,n,3) bent evenly and turned so that the last joint meets `targets` (b,3) where it can (the
    nearest distance otherwise); joint 0 stays."""
    base = start[:, 0]
    segments = np.diff(start, axis=1)  # (b,s,3)
    end = start[:, -1] - base
    to_target = targets - base
    want = norm(to_target)
    # The bend axis: the chain's own curvature where it has one (a fixed side to curl to, so the bend does
    # not flip over when the target passes the chain's line), else the turn from its end to the target.
    curvature = cross(segments[:, :-1], segments[:, 1:]).sum(axis=1)
    scale = np.mean(norm(segments), axis=1) ** 2
    axis = np.where((norm(curvature) > _CURVED * scale)[:, None], curvature, cross(end, to_target))
    flat = norm(axis) <= 1e-9 * np.maximum(norm(end) * want, 1e-300)
    axis = np.where(flat[:, None], any_perpendicular(np.where(norm(end)[:, None] > 0, end, 1.0)), axis)
    steps = np.arange(segments.shape[1], dtype=np.float64)

    def bent(angle):  # angle (b,m) -> chain ends relative to the base (b,m,3)
        turned = rotate_about_axis(segments[:, None], axis[:, None, None], angle[..., None] * steps)
        return turned.sum(axis=2)

    # The bend toward the side the chain turns to (positive about the axis) first, the other way where that
    # never reaches the wanted distance: the first grid cell whose distance crosses the wanted one.
    lo = np.full(len(start), np.nan)
    hi = np.full(len(start), np.nan)
    for sign in (1.0, -1.0):
        todo = np.isnan(lo)
        angles = np.broadcast_to(sign * _GRID, (len(start), _GRID.size))
        gap = norm(bent(angles)) - want[:, None]  # (b,m)
        crossed = np.sign(gap[:, 1:]) != np.sign(gap[:, :1])
        first = np.argmax(crossed, axis=1)
        take = todo & crossed.any(axis=1)
        lo = np.where(take, sign * _GRID[first], lo)
        hi = np.where(take, sign * _GRID[first + 1], hi)
    # Out of reach either way: the grid angle nearest the wanted distance (the bisection below keeps it).
    none = np.isnan(lo)
    if np.any(none):
        grid = np.concatenate([-_GRID[:0:-1], _GRID])
        gap = norm(bent(np.broadcast_to(grid, (len(start), grid.size)))) - want[:, None]
        nearest = grid[np.argmin(np.abs(gap), axis=1)]
        lo, hi = np.where(none, nearest, lo), np.where(none, nearest, hi)
    gap_lo = norm(bent(lo[:, None]))[:, 0] - want
    for _ in range(_REFINE):
        mid = 0.5 * (lo + hi)
        gap_mid = norm(bent(mid[:, None]))[:, 0] - want
        same = np.sign(gap_mid) == np.sign(gap_lo)
        lo, gap_lo = np.where(same, mid, lo), np.where(same, gap_mid, gap_lo)
        hi = np.where(same, hi, mid)
    angle = 0.5 * (lo + hi)
    turned = rotate_about_axis(segments, axis[:, None], angle[:, None] * steps)
    swing = swing_rotation(turned.sum(axis=1), to_target)
    placed = base[:, None] + np.concatenate([np.zeros_like(base[:, None]),
                                             np.cumsum(apply_matrix(swing[:, None], turned), axis=1)], axis=1)
    good = (want > 0.0) & np.all(np.isfinite(placed), axis=(1, 2))
    return np.where(good[:, None, None], placed, start)
