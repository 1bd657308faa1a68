"""FABRIK on one chain without limits or obstacles in plain Python floats (math.sqrt, no numpy per step).

numpy's per-call overhead dominates on a 4-joint arm, so plain floats are several times faster than the batch
path (chain_model.py); both do the same floating-point operations in the same order, so they agree to rounding.
"""

import math

import numpy as np

from .errors import SolverInputError
from .chain_types import (_COINCIDENT, _NUDGE, _NUDGES, _STALL, MIN_SEGMENT_LENGTH, ChainResult, _final_status,
                          _unreachable_reason)


def _solve_plain(positions, target, settings):
    if not isinstance(positions, np.ndarray):
        try:
            positions = np.asarray(positions, dtype=np.float64)
        except (TypeError, ValueError) as ex:
            raise SolverInputError(f"positions must be numbers: {ex}") from None
    if positions.ndim != 2 or positions.shape[1] != 3:
        raise SolverInputError(f"positions must have shape (n,3), got {positions.shape}")
    rows = positions.tolist()
    n = len(rows)
    if n < 2:
        raise SolverInputError("a chain needs at least 2 joints")
    try:
        px = [float(r[0]) for r in rows]
        py = [float(r[1]) for r in rows]
        pz = [float(r[2]) for r in rows]
        tl = target.tolist() if isinstance(target, np.ndarray) else list(target)
        if len(tl) != 3:
            raise SolverInputError("target must have shape (3,)")
        tx, ty, tz = float(tl[0]), float(tl[1]), float(tl[2])
    except (TypeError, ValueError) as ex:
        if isinstance(ex, SolverInputError):
            raise
        raise SolverInputError(f"positions and target must be numbers: {ex}") from None
    # One sum tells whether everything is finite (NaN/inf propagate); only an overflow would need the slow look.
    if not math.isfinite(sum(px) + sum(py) + sum(pz)):
        if not all(math.isfinite(v) for v in px + py + pz):
            raise SolverInputError("positions have NaN/inf")
    if not (math.isfinite(tx) and math.isfinite(ty) and math.isfinite(tz)):
        raise SolverInputError("target has NaN/inf")

    sqrt = math.sqrt
    m = n - 1
    lengths = []
    for i in range(m):
        dx, dy, dz = px[i + 1] - px[i], py[i + 1] - py[i], pz[i + 1] - pz[i]
        length = sqrt(dx * dx + dy * dy + dz * dz)
        if length <= MIN_SEGMENT_LENGTH:
            raise SolverInputError(f"segment {i} has zero length")
        lengths.append(length)
    total = lengths[0]
    for i in range(1, m):
        total = total + lengths[i]
    inner = max(2.0 * max(lengths) - total, 0.0)
    bx, by, bz = px[0], py[0], pz[0]
    dx, dy, dz = tx - bx, ty - by, tz - bz
    dist = sqrt(dx * dx + dy * dy + dz * dz)
    tol = settings.tolerance
    last = m

    if dist > total:
        # Out of reach: one backward pass with every segment aimed at the target stretches the chain along
        # the line base -> target.
        ox, oy, oz = px[:], py[:], pz[:]
        for i in range(m):
            dx, dy, dz = tx - px[i], ty - py[i], tz - pz[i]
            d = sqrt(dx * dx + dy * dy + dz * dz)
            if not d > lengths[i] * _COINCIDENT:
                dx, dy, dz = ox[i + 1] - ox[i], oy[i + 1] - oy[i], oz[i + 1] - oz[i]
                d = sqrt(dx * dx + dy * dy + dz * dz)
            s = lengths[i] / d
            px[i + 1], py[i + 1], pz[i + 1] = px[i] + dx * s, py[i] + dy * s, pz[i] + dz * s
        dx, dy, dz = px[last] - tx, py[last] - ty, pz[last] - tz
        residual = sqrt(dx * dx + dy * dy + dz * dz)
        return ChainResult(np.array([px, py, pz]).T, 1, residual, False, "unreachable",
                           _unreachable_reason(dist, total, inner))

    dx, dy, dz = px[last] - tx, py[last] - ty, pz[last] - tz
    residual = sqrt(dx * dx + dy * dy + dz * dz)
    iterations = 0
    stalled = False
    max_iterations = settings.max_iterations
    stall = tol * _STALL
    nudges = 0
    while residual > tol and iterations < max_iterations:
        ox, oy, oz = px[:], py[:], pz[:]
        # Forward: pin the effector to the target, place each joint toward its old position.
        px[last], py[last], pz[last] = tx, ty, tz
        for i in range(m - 1, -1, -1):
            ax, ay, az = px[i + 1], py[i + 1], pz[i + 1]
            dx, dy, dz = px[i] - ax, py[i] - ay, pz[i] - az
            d = sqrt(dx * dx + dy * dy + dz * dz)
            if not d > lengths[i] * _COINCIDENT:
                dx, dy, dz = ox[i] - ox[i + 1], oy[i] - oy[i + 1], oz[i] - oz[i + 1]
                d = sqrt(dx * dx + dy * dy + dz * dz)
            s = lengths[i] / d
            px[i], py[i], pz[i] = ax + dx * s, ay + dy * s, az + dz * s
        # Backward: pin the base, place each joint toward its forward-pass position.
        px[0], py[0], pz[0] = bx, by, bz
        for i in range(m):
            ax, ay, az = px[i], py[i], pz[i]
            dx, dy, dz = px[i + 1] - ax, py[i + 1] - ay, pz[i + 1] - az
            d = sqrt(dx * dx + dy * dy + dz * dz)
            if not d > lengths[i] * _COINCIDENT:
                dx, dy, dz = ox[i + 1] - ox[i], oy[i + 1] - oy[i], oz[i + 1] - oz[i]
                d = sqrt(dx * dx + dy * dy + dz * dz)
            s = lengths[i] / d
            px[i + 1], py[i + 1], pz[i + 1] = ax + dx * s, ay + dy * s, az + dz * s
        iterations += 1
        ex, ey, ez = px[last], py[last], pz[last]
        dx, dy, dz = ex - tx, ey - ty, ez - tz
        residual = sqrt(dx * dx + dy * dy + dz * dz)
        dx, dy, dz = ex - ox[last], ey - oy[last], ez - oz[last]
        if residual > tol and sqrt(dx * dx + dy * dy + dz * dz) < stall:
            if nudges < _NUDGES and iterations < max_iterations:
                ux, uy, uz = _nudge_direction(tx - bx, ty - by, tz - bz, px[1] - bx, py[1] - by, pz[1] - bz, nudges)
                for i in range(1, m):
                    k = lengths[i - 1] * _NUDGE
                    px[i], py[i], pz[i] = px[i] + ux * k, py[i] + uy * k, pz[i] + uz * k
                nudges += 1
                continue
            stalled = True
            break
    reachable = dist >= inner
    status, reason = _final_status(residual <= tol, reachable, dist, total, inner, stalled, iterations,
                                   False, False)
    return ChainResult(np.array([px, py, pz]).T, iterations, residual, reachable, status, reason)


def _nudge_direction(vx, vy, vz, fx, fy, fz, k):
    """Unit sideways direction of nudge number k for the line v = base->target (or, for a target at the
    base, the first segment f): geometry.any_perpendicular(v) for k = 0, v x that for k = 1. Plain floats
    written to round exactly like the numpy path."""
    sqrt = math.sqrt
    if not sqrt(vx * vx + vy * vy + vz * vz) > 0.0:
        vx, vy, vz = fx, fy, fz
    n = sqrt(vx * vx + vy * vy + vz * vz)
    vx, vy, vz = vx / n, vy / n, vz / n
    ax, ay, az = abs(vx), abs(vy), abs(vz)
    ex, ey, ez = (1.0, 0.0, 0.0) if ax <= ay and ax <= az else ((0.0, 1.0, 0.0) if ay <= az else (0.0, 0.0, 1.0))
    px, py, pz = vy * ez - vz * ey, vz * ex - vx * ez, vx * ey - vy * ex
    n = sqrt(px * px + py * py + pz * pz)
    px, py, pz = px / n, py / n, pz / n
    if k == 0:
        return px, py, pz
    qx, qy, qz = vy * pz - vz * py, vz * px - vx * pz, vx * py - vy * px
    n = sqrt(qx * qx + qy * qy + qz * qz)
    return qx / n, qy / n, qz / n

