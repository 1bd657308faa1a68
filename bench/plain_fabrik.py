"""Plain multi-end-effector FABRIK (Aristidou & Lasenby 2011) on the body model's chains: the benches' baseline.

Written here, vectorised over frames the same way as the product's solver (numpy over frames, converged frames
masked out), so a speed ratio against it measures the algorithm, not the implementation. Every joint is free
(no limits, no obstacles). The pelvis and the hips are fixed (FABRIK cannot move its root); the arms (and the
head) hang from the SC through their rigid SC -> base link, a segment like any other here; the SC goes to the
unweighted centroid of their proposals; legs are single chains from the fixed hips. Stopping rule: every
target met within `tolerance`, or no end effector moved by more than tolerance * 1e-3 in an iteration, or
`max_iterations`.

A limb has a target on every frame or on none (`targets` rows of NaN); a limb hanging from the SC without a
target is carried along by the SC's displacement.
"""

import numpy as np

from fullbody_adjust.solver.body.model import LIMB_OF_EFFECTOR

BODY_CHAINS = ("trunk", "arm.L", "arm.R", "leg.L", "leg.R")


def _place(anchor, toward, length, fallback):
    d = toward - anchor
    n = np.linalg.norm(d, axis=-1, keepdims=True)
    ok = n > 1e-12 * length[..., None]
    d = np.where(ok, d, fallback)
    n = np.linalg.norm(d, axis=-1, keepdims=True)
    return anchor + d * (length[..., None] / n)


def _reach_in(p, target, lengths, prev):
    """Forward pass of one chain (b,n,3) in place: the end onto the target, each joint toward its child."""
    p[:, -1] = target
    for i in range(p.shape[1] - 2, -1, -1):
        p[:, i] = _place(p[:, i + 1], p[:, i], lengths[:, i], prev[:, i] - prev[:, i + 1])


def _reach_out(p, lengths, prev):
    """Backward pass of one chain (b,n,3) in place from its (already placed) joint 0."""
    for i in range(p.shape[1] - 1):
        p[:, i + 1] = _place(p[:, i], p[:, i + 1], lengths[:, i], prev[:, i + 1] - prev[:, i])


def plain_fabrik(model, heads, tails, targets, effectors, tolerance=1e-5, max_iterations=200):
    """heads/tails (F,J,3) start poses; targets (F,E,3) for `effectors`. Returns ({chain: joints (F,n,3)} for
    the trunk, arms, legs (and the head chain when the model has one), iterations (F,))."""
    targets = np.asarray(targets, dtype=np.float64)
    tgt = {}
    for k, e in enumerate(effectors):
        has = ~np.isnan(targets[:, k]).any(axis=1)
        if has.any() and not has.all():
            raise ValueError(f"{e}: a target on some frames only")
        if has.all():
            tgt[LIMB_OF_EFFECTOR[e]] = targets[:, k]
    names = [n for n in model.limbs if n in BODY_CHAINS or n == "head"]
    chains = {n: model.limbs[n].joints(heads, tails).copy() for n in names}
    sc_limbs = [n for n in names if model.limbs[n].hub == "sc"]
    links = {a: chains[a][:, 0] - chains["trunk"][:, -1] for a in sc_limbs}
    link_len = {a: np.linalg.norm(v, axis=-1) for a, v in links.items()}
    lengths = {n: np.linalg.norm(np.diff(c, axis=1), axis=-1) for n, c in chains.items()}
    pulling = [a for a in sc_limbs if a in tgt]
    legs = [n for n in ("leg.L", "leg.R") if n in tgt]
    base_trunk = chains["trunk"][:, 0].copy()
    f = heads.shape[0]
    iterations = np.zeros(f, dtype=int)

    def residual(c, rows):
        if not tgt:
            return np.zeros(len(rows))
        return np.max(np.stack([np.linalg.norm(c[n][:, -1] - tgt[n][rows], axis=-1) for n in tgt]), axis=0)

    every = np.arange(f)
    active = residual(chains, every) > tolerance
    while np.any(active):
        rows = np.nonzero(active)[0]
        c = {n: chains[n][rows].copy() for n in chains}
        prev = {n: v.copy() for n, v in c.items()}
        tr = c["trunk"]
        if pulling:
            # Forward: effectors to targets, back toward the SC; the SC = centroid of the proposals.
            proposals = []
            for a in pulling:
                _reach_in(c[a], tgt[a][rows], lengths[a][rows], prev[a])
                proposals.append(_place(c[a][:, 0], tr[:, -1], link_len[a][rows], -links[a][rows]))
            _reach_in(tr, np.mean(proposals, axis=0), lengths["trunk"][rows], prev["trunk"])
            # Backward: root pinned, out to the SC, then each limb from the SC.
            tr[:, 0] = base_trunk[rows]
            _reach_out(tr, lengths["trunk"][rows], prev["trunk"])
            for a in sc_limbs:
                if a in tgt:
                    c[a][:, 0] = _place(tr[:, -1], c[a][:, 0], link_len[a][rows], links[a][rows])
                    _reach_out(c[a], lengths[a][rows], prev[a])
                else:
                    c[a] += (tr[:, -1] - prev["trunk"][:, -1])[:, None]
        for leg in legs:
            _reach_in(c[leg], tgt[leg][rows], lengths[leg][rows], prev[leg])
            c[leg][:, 0] = chains[leg][rows, 0]  # the hip is fixed: chains[leg] still holds it
            _reach_out(c[leg], lengths[leg][rows], prev[leg])
        for n in chains:
            chains[n][rows] = c[n]
        iterations[rows] += 1
        res = residual(c, rows)
        moved = np.max(np.stack([np.linalg.norm(c[n][:, -1] - prev[n][:, -1], axis=-1) for n in tgt]), axis=0)
        done = (res <= tolerance) | (moved < tolerance * 1e-3) | (iterations[rows] >= max_iterations)
        active[rows[done]] = False
    return chains, iterations
