"""FABRIK on trees: several end effectors meeting at sub-bases (paper §4.2).

Strategies for the position of a sub-base, where the chains of several end effectors meet:
- 'centroid': plain FABRIK with multiple end effectors (Aristidou & Lasenby 2011): each forward stage
  reaches from the effectors to the sub-base; the sub-base goes to the unweighted centroid of the branches'
  proposals; the forward stage continues from there toward the root; the backward stage places the chains
  from the fixed root outward. The baseline.
- 'weighted' (variant 1, eq. 4): the same, with the sub-base at the priority-weighted mean of the proposals;
  a branch's weight is the highest priority of the effectors in it. Priorities must be > 0.
- 'sequential' (variant 2): the simple root -> effector chains are solved one after another from the lowest
  priority to the highest, so the highest priority task is met whenever it is reachable on its own. Then a
  settle pass: in decreasing priority, every lower task re-solves only the part of its chain below its
  junction with the joints already held by higher tasks, so it does its best without moving them.

Input: joint positions (n,3), parents (n,) with -1 for the single root (the fixed base), effectors as
(joint, target, priority) tuples or Effector objects (higher priority wins).

Supported: obstacles (Boxes) in every strategy (each chain's passes use the chain solver's collision
response). Not supported: joint limits (solve limited limbs as chains with solve_chain, as the body solver
does). Joints that lead to no effector (passive branches) keep their shape and translate with the joint they
hang from; they are not checked against obstacles while solving (the result's reasons report it if they end
up inside one).
"""

from dataclasses import dataclass

import numpy as np

from .chain import ChainSettings, solve_chain
from .chain_model import ChainModel
from .chain_types import _STALL
from .errors import SolverInputError
from .geometry import all_set, any_set
from .obstacles import as_boxes, points_inside, segments_cross

STRATEGIES = ("centroid", "weighted", "sequential")


@dataclass(frozen=True)
class Effector:
    joint: int
    target: np.ndarray
    priority: float = 1.0


@dataclass
class TreeResult:
    positions: np.ndarray  # (n,3)
    iterations: int  # FABRIK iterations: tree iterations, or for 'sequential' the sum over its chain solves
    residuals: np.ndarray  # (E,) distance of each effector to its target, in the order given
    status: list  # (E,) chain status strings (see chain.STATUSES)
    reasons: list  # (E,) explanations
    strategy: str
    history: np.ndarray  # (H, E) residuals after each iteration ('sequential': after each chain solve)
    history_iterations: np.ndarray  # (H,) iterations done when each history row was taken


class _Tree:
    """Validated topology: children, the root path of every joint, and the chains between key joints
    (root, effectors, joints where several effector paths part)."""

    def __init__(self, positions, parents, effectors):
        p = np.asarray(positions, dtype=np.float64)
        if p.ndim != 2 or p.shape[1] != 3:
            raise SolverInputError(f"positions must have shape (n,3), got {p.shape}")
        n = p.shape[0]
        if n < 2:
            raise SolverInputError("a tree needs at least 2 joints")
        if not all_set(np.isfinite(p)):
            raise SolverInputError("positions have NaN/inf")
        par = np.asarray(parents)
        if par.shape != (n,) or not np.issubdtype(par.dtype, np.integer):
            raise SolverInputError(f"parents must be {n} integers")
        roots = np.nonzero(par == -1)[0]
        if roots.size != 1:
            raise SolverInputError(f"the tree needs exactly one root (parent -1), found {roots.size}")
        if any_set((par < -1) | (par >= n)):
            raise SolverInputError("a parent index is out of range")
        self.n, self.root, self.parents = n, int(roots[0]), par.astype(np.int64)
        self.paths = []  # root -> joint, for every joint
        for j in range(n):
            path, k = [j], j
            while self.parents[k] != -1:
                k = int(self.parents[k])
                path.append(k)
                if len(path) > n:
                    raise SolverInputError(f"the parents form a cycle through joint {j}")
            self.paths.append(path[::-1])
        for j in range(n):
            if j != self.root:
                length = float(np.linalg.norm(p[j] - p[self.parents[j]]))
                if length <= 1e-12:
                    raise SolverInputError(f"segment {self.parents[j]}->{j} has zero length")

        self.effectors = []
        for e in effectors:
            e = e if isinstance(e, Effector) else Effector(*e)
            if isinstance(e.joint, bool) or not isinstance(e.joint, (int, np.integer)) or not 0 <= e.joint < n:
                raise SolverInputError(f"effector joint {e.joint!r} is not a joint index")
            if e.joint == self.root:
                raise SolverInputError("the root is fixed: it cannot be an effector")
            t = np.asarray(e.target, dtype=np.float64)
            if t.shape != (3,):
                raise SolverInputError(f"target of effector {e.joint} must have shape (3,)")
            if not all_set(np.isfinite(t)):
                raise SolverInputError(f"target of effector {e.joint} has NaN/inf")
            if not np.isfinite(e.priority):
                raise SolverInputError(f"priority of effector {e.joint} is not finite")
            self.effectors.append(Effector(int(e.joint), t, float(e.priority)))
        if not self.effectors:
            raise SolverInputError("at least one effector is needed")
        if len({e.joint for e in self.effectors}) != len(self.effectors):
            raise SolverInputError("two effectors share a joint")

        # Active joints lie on a root -> effector path; key joints end chains.
        active = set()
        for e in self.effectors:
            active.update(self.paths[e.joint])
        self.active = active
        active_children = {j: [] for j in active}
        for j in active:
            if j != self.root:
                active_children[int(self.parents[j])].append(j)
        eff_joints = {e.joint for e in self.effectors}
        key = {j for j in active if j == self.root or j in eff_joints or len(active_children[j]) != 1}
        self.chains = []  # joint lists start key -> end key
        for k in key:
            if k == self.root:
                continue
            chain, j = [k], k
            while True:
                j = int(self.parents[j])
                chain.append(j)
                if j in key:
                    break
            self.chains.append(chain[::-1])
        depth = {j: len(self.paths[j]) for j in range(n)}
        self.chains.sort(key=lambda c: depth[c[0]])  # parents before children
        # Priority of a chain = highest priority of the effectors beyond it (eq. 4's weight of that branch).
        self.chain_weight = []
        for c in self.chains:
            below = [e.priority for e in self.effectors if c[-1] in self.paths[e.joint]]
            self.chain_weight.append(max(below))
        # Passive joints follow their nearest active ancestor.
        self.anchor = np.array([j if j in active else next(a for a in reversed(self.paths[j]) if a in active)
                                for j in range(n)])
        self.segments = np.array([[self.parents[j], j] for j in range(n) if j != self.root], dtype=np.int64)


def solve_tree(positions, parents, effectors, *, strategy="centroid", settings=ChainSettings(), obstacles=None):
    """Move the effectors of a joint tree to their targets; the root is fixed. See the module docstring."""
    if strategy not in STRATEGIES:
        raise SolverInputError(f"strategy must be one of {', '.join(STRATEGIES)}, got {strategy!r}")
    if not isinstance(settings, ChainSettings):
        raise SolverInputError("settings must be a ChainSettings")
    obstacles = as_boxes(obstacles)
    if obstacles is not None and obstacles.batched:
        raise SolverInputError("trees take shared boxes (K,3)")
    if obstacles is not None and len(obstacles) == 0:
        obstacles = None
    tree = _Tree(positions, parents, effectors)
    if strategy == "weighted" and any(e.priority <= 0 for e in tree.effectors):
        raise SolverInputError("the weighted strategy needs priorities > 0")
    start = np.asarray(positions, dtype=np.float64)
    if strategy == "sequential":
        X, iterations, history, notes = _solve_sequential(tree, start, settings, obstacles)
    else:
        X, iterations, history, notes = _solve_fabrik(tree, start, settings, obstacles, strategy == "weighted")
    X = start + (X - start)[tree.anchor]  # passive joints translate with their anchor (active ones: anchor = self)
    return _result(tree, start, X, iterations, history, notes, settings, obstacles, strategy)


def _residuals(tree, X):
    return np.array([np.linalg.norm(X[e.joint] - e.target) for e in tree.effectors])


def _solve_fabrik(tree, start, settings, obstacles, weighted):
    """Multi-end-effector FABRIK with the sub-base rule 'centroid' or eq. 4's weighted mean."""
    tol = settings.tolerance
    eff_target = {e.joint: (e.target, e.priority) for e in tree.effectors}
    models = []
    for c in tree.chains:
        end = c[-1]
        target = eff_target[end][0] if end in eff_target else start[end]
        models.append(ChainModel(start[c][None], target[None], settings, None, obstacles, None,
                                 end_is_target=end in eff_target, base_is_fixed=c[0] == tree.root))
    rows = np.zeros(1, dtype=np.int64)
    X = start.copy()
    history, counts = [], []
    residual = _residuals(tree, X)
    iterations = 0
    stalled = False
    while any_set(residual > tol) and iterations < settings.max_iterations:
        before = X.copy()
        F = X.copy()  # forward-stage positions
        proposals = {}  # sub-base joint -> [(position, weight)]
        for c, model, w in reversed(list(zip(tree.chains, models, tree.chain_weight))):  # children first
            end = c[-1]
            props = proposals.get(end, [])
            if end in eff_target:
                props = props + [eff_target[end]]
            pos = np.array([q for q, _ in props])
            if weighted:
                wts = np.array([wt for _, wt in props])
                tip = (pos * wts[:, None]).sum(axis=0) / wts.sum()
            else:
                tip = pos.mean(axis=0)
            P = X[c][None].copy()
            model.forward(P, rows, X[c][None], X[c][None], tip=tip[None])
            F[c[1:]] = P[0, 1:]
            proposals.setdefault(c[0], []).append((P[0, 0], w))
        for c, model in zip(tree.chains, models):  # parents first: each chain's start is already placed
            P = F[c][None].copy()
            model.backward(P, rows, F[c][None], before[c][None], before[c][None], root=X[c[0]][None])
            X[c[1:]] = P[0, 1:]
        iterations += 1
        residual = _residuals(tree, X)
        history.append(residual)
        counts.append(iterations)
        moved = max(np.linalg.norm(X[e.joint] - before[e.joint]) for e in tree.effectors)
        if any_set(residual > tol) and moved < tol * _STALL:
            stalled = True
            break
    how = f"stalled after {iterations} iterations" if stalled else f"iteration cap {iterations} reached"
    notes = {e.joint: (None, f"not met together with the other targets ({how})") for e in tree.effectors}
    return X, iterations, (np.array(history).reshape(-1, len(tree.effectors)), np.array(counts, dtype=np.int64)), notes


def _translate_off_path(tree, X, path, new):
    """Put the joints of `path` at `new`; every other joint hanging from a path joint (not through another
    path joint) translates with it."""
    delta = new - X[path]
    on_path = {j: i for i, j in enumerate(path)}
    shift = np.zeros_like(X)
    for j in range(tree.n):
        if j in on_path:
            continue
        # the deepest path joint on j's root path, if j hangs below the path
        for a in reversed(tree.paths[j]):
            if a in on_path:
                shift[j] = delta[on_path[a]]
                break
    X += shift
    X[path] = new


def _solve_sequential(tree, start, settings, obstacles):
    """Variant 2: root -> effector chains from the lowest priority to the highest, then the settle pass."""
    order = sorted(range(len(tree.effectors)), key=lambda i: tree.effectors[i].priority)  # stable
    X = start.copy()
    iterations = 0
    history, counts = [], []
    notes = {}
    for i in order:
        e = tree.effectors[i]
        path = tree.paths[e.joint]
        res = solve_chain(X[path], e.target, settings=settings, obstacles=obstacles)
        _translate_off_path(tree, X, path, res.positions)
        iterations += res.iterations
        history.append(_residuals(tree, X))
        counts.append(iterations)
        notes[e.joint] = (res.status, res.reason)
    top = tree.effectors[order[-1]]
    held = set(tree.paths[top.joint])
    for i in reversed(order[:-1]):
        e = tree.effectors[i]
        path = tree.paths[e.joint]
        k = max(idx for idx, j in enumerate(path) if j in held)
        sub = path[k:]
        if len(sub) >= 2:
            res = solve_chain(X[sub], e.target, settings=settings, obstacles=obstacles)
            _translate_off_path(tree, X, sub, res.positions)
            iterations += res.iterations
            history.append(_residuals(tree, X))
            counts.append(iterations)
            reason = res.reason if k == 0 else f"{res.reason} (solved below joint {path[k]}, held by higher priorities)"
            notes[e.joint] = (res.status, reason)
        else:
            notes[e.joint] = ("blocked", "its joint is held by a higher-priority task")
        held.update(path)
    return X, iterations, (np.array(history).reshape(-1, len(tree.effectors)), np.array(counts, dtype=np.int64)), notes


def _result(tree, start, X, iterations, history, notes, settings, obstacles, strategy):
    tol = settings.tolerance
    residuals = _residuals(tree, X)
    lengths = {j: float(np.linalg.norm(start[j] - start[tree.parents[j]])) for j in range(tree.n) if j != tree.root}
    # Penetrations per joint / per segment (by child joint), ignoring boxes that contain the effector's target
    # for that effector's joint and last segment, and boxes that contain the root for the root's segments.
    bad_joint, bad_seg = {}, {}
    if obstacles is not None:
        nothing = np.zeros(len(obstacles), dtype=bool)
        ignore_end = {e.joint: points_inside(e.target, obstacles) for e in tree.effectors}
        ignore_root = points_inside(X[tree.root], obstacles)
        inside = points_inside(X, obstacles)
        crossing = segments_cross(X[tree.segments[:, 0]], X[tree.segments[:, 1]], obstacles)
        for j in range(tree.n):
            if j == tree.root:
                continue
            ins = inside[j] & ~ignore_end.get(j, nothing)
            if any_set(ins):
                bad_joint[j] = True
        for s, (a, j) in enumerate(tree.segments):
            cr = crossing[s] & ~ignore_end.get(int(j), nothing)
            if a == tree.root:
                cr = cr & ~ignore_root
            if any_set(cr):
                bad_seg[int(j)] = True
    status, reasons = [], []
    for e, r in zip(tree.effectors, residuals):
        path = tree.paths[e.joint]
        reach = sum(lengths[j] for j in path[1:])
        dist = float(np.linalg.norm(e.target - X[tree.root]))
        chain_status, chain_reason = notes.get(e.joint, (None, ""))
        if dist > reach:
            st, why = "unreachable", f"target is {dist - reach:.6g} beyond the reach {reach:.6g} from the root"
        elif r <= tol:
            st, why = "reached", "reached"
        elif strategy == "sequential" and chain_status is not None:
            st, why = chain_status, chain_reason
        else:
            st, why = "max_iterations", chain_reason
        extra = []
        if obstacles is not None:
            if any_set(points_inside(e.target, obstacles)):
                extra.append("target inside obstacle")
            hit = [j for j in path[1:] if j in bad_joint or j in bad_seg]
            if hit:
                extra.append(f"could not avoid obstacles at joints {hit}")
        if extra:
            st, why = "blocked", "; ".join(extra + [why])
        status.append(st)
        reasons.append(why)
    passive_hits = [j for j in range(tree.n) if j not in tree.active and (j in bad_joint or j in bad_seg)]
    if passive_hits:
        reasons = [r + f"; passive joints {passive_hits} end inside obstacles" for r in reasons]
    return TreeResult(X, int(iterations), residuals, status, reasons, strategy, history[0], history[1])
