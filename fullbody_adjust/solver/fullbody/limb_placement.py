"""Steps 2-4 of Algorithm 1 (paper §5): the top-down pass that places every bone once the sub-bases are known,
solving each limb from its base riding on its parent (LimbPlacement, owned by adjust._Problem; it uses the
problem's chains, targets, limits, obstacles and settings)."""

from dataclasses import dataclass

import numpy as np

from ..maths import lanes
from ..maths import vectors as vec
from ..body.model import CHAIN, ROOT
from ..chain.fabrik import solve_chain_batch
from ..chain.settings import ChainBatchResult, _final_status
from ..maths.geometry import all_set, any_set, apply_matrix, norm, stack_rows
from ..obstacles.easing import ClearanceEasing
from .limb_rotations import _EYE, LimbSolve, end_rotation, set_segment_rotations
from ..limits.joint_limits import HINGE, JointLimits, carry_axis
from ..obstacles.boxes import grown_clear_of, points_inside, segments_cross
from ..chain.two_bone_start import two_bone_start


class LimbPlacement:
    """The limbs' chain solves and the pass that places every bone from them, for the problem ``p``
    (adjust._Problem: its chains, targets, limits, obstacles and settings); ``easing`` retries the limbs their
    clearance kept from their targets."""

    def __init__(self, problem):
        self.p = problem
        self.easing = ClearanceEasing(problem, self)

    def _solve(self, name, rows, start, targets, carry=None):
        """solve_chain_batch on frames `rows` of limb `name` from chains `start` (b,n,3) to `targets` (b,3):
        _solve_stacked on this one limb."""
        return self._solve_stacked([ChainTask(name, rows, start, targets, carry)])[0]

    def _solve_stacked(self, tasks, ease=1.0, retry=False):
        """One solve_chain_batch for `tasks` (ChainTask), their rows stacked in order, with each limb's limits
        and its frames' obstacles (grown by `ease` times its clearance: _limb_boxes, _eased); one
        ChainBatchResult per task. The tasks' limbs share a _stack_key (chain
        length, per-joint limits): the chain solve treats its rows independently, so a stacked row equals the
        limb solved alone, and numpy's per-call cost is paid once for all of them. `carry` (b,3,3): the
        rotation that took the limb's start-pose chain to `start` (its parent's rotation), applied to joint 0's
        parent direction (and a hinge axis at joint 0), which are given at the start pose. The other hinge
        axes are carried from the start pose's own chain (hinge_reference; any reference the caller's limits
        had is replaced), the frame _segment_rotations writes the bones in.

        Warm start for a hinged limb (elbow, knee) whose end is not at its target yet: the last two segments
        are first placed by the two-bone solution in the plane of the start hinge axis carried to the
        target (two_bone_start), which keeps the elbow/knee near where it was (measured: without it the
        mean joint angle error of bench/fullbody.py rises from 0.118 to 0.144 rad); FABRIK and the chain's
        two-segment finish then settle the twist, the cones, obstacles and the clavicle. A pole (set_end_goals)
        sets that plane instead, on every frame that has one."""
        start = stack_rows([t.start for t in tasks])
        targets = stack_rows([t.targets for t in tasks])
        pole = stack_rows([self.p.limb_pole[t.name][t.rows] if t.name in self.p.limb_pole
                            else np.full((len(t.rows), 3), np.nan) for t in tasks])
        kwargs = {}
        pole_placed = False
        ll = self.p.limits.get(tasks[0].name)
        if ll is not None and ll.limits.any_active:
            parts = [self.p.limits[t.name].for_chains(self.p.chain0[t.name][t.rows], t.rows, t.carry) for t in tasks]
            lim = JointLimits.stack([part[0] for part in parts])
            pdir = None if parts[0][1] is None else stack_rows([part[1] for part in parts])
            axes, reference = lim.hinge_axis, lim.hinge_reference
            m = len(lim)
            if lim.kind[m - 1] == HINGE and m >= 2:
                warm = np.nonzero((norm(start[:, -1] - targets) > self.p.settings.chain.tolerance)
                                  | np.isfinite(pole[:, 0]))[0]
                if warm.size:
                    at_start = carry_axis(axes[warm, m - 1], reference[warm, m - 1],
                                          start[warm, m - 1] - start[warm, m - 2])
                    start = start.copy()
                    start[warm] = two_bone_start(start[warm], targets[warm], at_start, pole[warm])
                pole_placed = True
            kwargs["limits"] = lim
            kwargs["parent_directions"] = pdir
        pending = np.nonzero(np.isfinite(pole[:, 0]) & (not pole_placed))[0]
        if pending.size and start.shape[1] >= 3:  # a pole without a hinge limit: the same warm start
            start = start.copy()
            start[pending] = two_bone_start(start[pending], targets[pending], np.zeros((pending.size, 3)),
                                            pole[pending])
        if self.p.obstacles is not None:
            kwargs["obstacles"] = self._limb_boxes([(t.name, t.rows, t.start[:, 0], t.targets) for t in tasks], ease)
        res = solve_chain_batch(start, targets, settings=self.p.settings.chain, **kwargs)
        out = [res] if len(tasks) == 1 else _split(res, [len(t.rows) for t in tasks])
        for t, r in zip(tasks, out):
            self.p.iterations[t.rows] += r.iterations  # per task: two limbs' rows may be the same frames
        if self.p.obstacles is not None and not retry:
            self.easing._eased(tasks, out)
        return out

    def _limb_boxes(self, parts, ease=1.0):
        """The obstacle boxes a chain solve of `parts` [(limb, rows (b,), bases (b,3), targets (b,3))], their rows
        stacked in order, tests against: each limb's frames' boxes grown by its clearance (settings.clearance,
        obstacles.grown_clear_of: less near its base and target); the frames' boxes as they are where no limb
        of them has one (the paper's behaviour)."""
        rows = stack_rows([part[1] for part in parts])
        boxes = self.p.obstacles.select(rows)
        clearance = [ease * self.p.settings.clearance_of(part[0]) for part in parts]
        if not any(clearance):
            return boxes
        keep_out = np.stack([stack_rows([part[2] for part in parts]), stack_rows([part[3] for part in parts])], 1)
        return grown_clear_of(boxes, np.repeat(clearance, [len(part[1]) for part in parts]), keep_out)

    def _stack_key(self, task):
        """What limbs solved in one stacked chain solve must share: the chain length and, when limited, the
        per-joint limits and whether joint 0 has a parent direction."""
        ll = self.p.limits.get(task.name)
        if ll is None or not ll.limits.any_active:
            return task.start.shape[1], None
        return task.start.shape[1], ll.limits.per_joint_key(), ll.parent_direction is None

    def _propagate(self, delta, trunk):
        """Top-down pass over the bones, one hierarchy level at a time: new heads, tails and world rotation
        deltas; limbs other than the trunk are solved when their first bone is reached (their base then rides
        on its parent). Each level's bones are placed together, on every frame at once (one frame as a batch of
        one: a level holds a few bones, and numpy's cost per level is a small part of the limbs' solves)."""
        model, F, H0, T0 = self.p.model, self.p.F, self.p.H0, self.p.T0
        J = len(model.names)
        heads = H0.copy()
        rot = np.empty((F, J, 3, 3))
        rot[...] = _EYE
        moved = np.zeros((F, J), dtype=bool)
        solves = {"trunk": trunk}

        for rigid, par, limb_bones in self.p.prepared.levels:
            # Rigid children of their parents (overridden below for solved chain bones); where the parent did
            # not move, a bone stays as initialised (its parent's rotation is then the identity).
            _carry(heads, rot, moved, H0, rigid, par)
            # The limbs starting on this level ride on parents placed on earlier levels: solved together.
            starts = {name: (heads[:, j], rot[:, p] if p >= 0 else None,
                             moved[:, p] if p >= 0 else np.zeros(F, dtype=bool))
                      for j, p, role, name, k in limb_bones if role == CHAIN and k == 0 and name not in solves}
            if starts:
                solves.update(self._solve_limbs(starts))
            for j, p, role, name, k in limb_bones:
                if role == ROOT:
                    heads[:, j] = H0[:, j] + delta  # x + 0.0 == x: an unmoved root stays bit-exact
                    moved[:, j] = (delta != 0.0).any(axis=1)
                    continue
                ls = solves[name]
                s = ls.placed_frames()
                if s is not None:
                    if role == CHAIN:
                        heads[s, j] = ls.joints[s, k]
                        rot[s, j] = ls.segment_rotations(self.p.chain0[name], self.p.limits.get(name))[s, k]
                    else:  # hands, feet and the head keep their world orientation on a solved limb
                        heads[s, j] = ls.joints[s, -1]
                        rot[s, j] = _EYE
                    moved[s, j] = True
                if role != CHAIN and name in self.p.end_turns:  # ... or turn toward a wanted orientation
                    w = np.nonzero(np.isfinite(self.p.end_turns[name][:, 0, 0]))[0]
                    if w.size:
                        rot[w, j] = end_rotation(self.p.end_turns[name][w], rot[w, p], T0[w, j] - H0[w, j])
                        moved[w, j] = True
        _carry(heads, rot, moved, H0, *self.p.prepared.leaves)  # fingers, face...: on their nearest placed ancestor
        tails = np.where(moved[..., None], heads + apply_matrix(rot, T0 - H0), T0) if any_set(moved) else T0.copy()
        return heads, tails, rot, solves

    def _solve_limbs(self, starts):
        """{limb: LimbSolve} for the limbs {name: (base, parent_rot, parent_moved)} (_start_limb); the chain
        solves of limbs with the same _stack_key (left and right arms, legs) run as one stacked solve, and so
        do their segment rotations."""
        solves, tasks = {}, []
        for name, (base, parent_rot, parent_moved) in starts.items():
            solves[name], task = self._start_limb(name, base, parent_rot, parent_moved)
            if task is not None:
                tasks.append(task)
        for group in _group_limbs(tasks, self._stack_key):
            for task, res in zip(group, self._solve_stacked(group)):
                ls, rows = solves[task.name], task.rows
                ls.joints[rows] = res.positions
                ls.status[rows] = res.status
                ls.reason[rows] = res.reason
                # The chain returns a valid start pose that meets its target untouched (0 iterations).
                kept = (res.iterations == 0) & task.still & np.all(res.positions == self.p.chain0[task.name][rows],
                                                                   axis=(1, 2))
                ls.solved[rows[kept]] = False
            # Their segment rotations too, in one call (_propagate then finds them computed).
            set_segment_rotations([solves[t.name] for t in group], [self.p.chain0[t.name] for t in group],
                                  [self.p.limits.get(t.name) for t in group])
        return solves

    def _start_limb(self, name, base, parent_rot, parent_moved):
        """Limb `name` on the frames where its effector has a target, from its base `base` (F,3) riding on its
        parent (rotation parent_rot (F,3,3), moved (F,) bool); the start chain is the old one carried rigidly.
        A limb whose parent did not move and whose start pose already meets its target (clear of the
        obstacles; within the caller's limits, if given) stays exactly as it was: not solved, so its bones keep
        their positions bit-exact and their rotations exactly identity ("moves only the joints that need to").
        Returns its LimbSolve as carried (the caller writes the solved frames in) and the ChainTask of the frames
        left to solve (None if none)."""
        F = self.p.F
        c0 = self.p.chain0[name]
        r = np.broadcast_to(_EYE, (F, 3, 3)) if parent_rot is None else parent_rot
        if any_set(parent_moved):
            carried = base[:, None, :] + np.einsum("fij,fkj->fki", r, c0 - c0[:, :1])
            carried = np.where(parent_moved[:, None, None], carried, c0)  # (c0 - b) + b may differ from c0 by 1 ulp
        else:
            carried = c0.copy()
        solved = self.p.limb_active[name].copy()
        status = np.full(F, "", dtype=object)
        reason = np.full(F, "", dtype=object)
        rows = np.nonzero(solved)[0]
        untouched = self._untouched_start(name, rows, parent_moved)
        if any_set(untouched):
            # The chain solve's status of a start at its target within reach: reached in 0 iterations.
            done = rows[untouched]
            status[done], reason[done] = _final_status(True, True, 0.0, 1.0, 0.0, False, 0, False, False)
            solved[rows[untouched]] = False
            rows = rows[~untouched]
        task = None
        if rows.size:
            task = ChainTask(name, rows, carried[rows], self.p.limb_target[name][rows], r[rows], ~parent_moved[rows])
        return LimbSolve(carried, solved, status, reason), task

    def _untouched_start(self, name, rows, parent_moved):
        """(b,) bool over frames `rows`: limb `name` stays exactly as it started, as a chain solve returns a start
        it finds nothing to do about (0 iterations, status reached): parent not moved, the target within reach
        and met at the start and, with obstacles, every joint and segment and the target outside every box;
        known from the prepared start pose without building a chain solve. The default limits do not enter:
        they bound motion (limits/start_range.py), and a limb that need not move makes none, wherever its start lies.
        Limits the caller gave are left to the chain solve, which moves a start that breaks them."""
        keep = ~parent_moved[rows]
        if not any_set(keep):
            return keep
        c0, target = self.p.chain0[name][rows], self.p.limb_target[name][rows]
        tol = self.p.settings.chain.tolerance  # a straight limb on its target reaches it, however its lengths round
        keep &= lanes.run(_meets_within_reach, (c0[:, -1], c0[:, 0], target), tol,
                          values=(self.p.reach[name][rows],)) == 1.0
        if any_set(keep) and self.p.obstacles is not None:
            # Clear of every box, the chain solve finds nothing to respond to and nothing to note.
            boxes = self._limb_boxes([(name, rows, c0[:, 0], target)])
            keep &= ~points_inside(c0, boxes).any(axis=(1, 2)) & ~points_inside(target, boxes).any(axis=1) \
                & ~segments_cross(c0[:, :-1], c0[:, 1:], boxes).any(axis=(1, 2))
        ll = self.p.limits.get(name)
        if any_set(keep) and ll is not None and ll.limits.any_active and not self.p.default_limits:
            # The caller's limits (a rig's own ranges, retargeting's): a chain solve checks the start against them.
            return np.zeros(rows.size, dtype=bool)
        return keep


@dataclass
class ChainTask:
    """One limb's chain solve on frames `rows` (b,): start chains (b,n,3), targets (b,3), `carry` (b,3,3) the
    parent's rotation since the start pose (None: not turned), `still` (b,) bool where the parent did not move
    (None: unknown)."""

    name: str
    rows: np.ndarray
    start: np.ndarray
    targets: np.ndarray
    carry: np.ndarray = None
    still: np.ndarray = None


def _meets_within_reach(end, base, goal, reach, tol):
    """1.0 where a limb from `base` to `end` meets `goal` within `tol` and the goal lies within `reach` (+ tol) of
    the base, else 0.0 (on components: maths/lanes.py)."""
    met = (vec.norm(vec.sub(end, goal)) <= tol) & lanes.not_(vec.norm(vec.sub(goal, base)) > reach + tol)
    return lanes.where(met, 1.0, 0.0)


def _group_limbs(tasks, key):
    """`tasks` in groups solved by one stacked chain solve each: those with equal key(task), in order."""
    groups = {}
    for t in tasks:
        groups.setdefault(key(t), []).append(t)
    return list(groups.values())


def _split(res, sizes):
    """ChainBatchResult `res` cut into consecutive pieces of `sizes` rows."""
    out, at = [], 0
    for size in sizes:
        cut = slice(at, at + size)
        out.append(ChainBatchResult(res.positions[cut], res.iterations[cut], res.residual[cut],
                                    res.reachable[cut], res.status[cut], res.reason[cut]))
        at += size
    return out


def _carry(heads, rot, moved, H0, bones, carriers):
    """Place `bones` (k,) rigidly on `carriers` (k,) already placed, in place: head carried by the carrier's
    rotation about its head, the same rotation; where a carrier did not move, a bone stays as initialised."""
    if bones.size:
        mc = moved[:, carriers]
        if any_set(mc):
            h = heads[:, carriers] + apply_matrix(rot[:, carriers], H0[:, bones] - H0[:, carriers])
            heads[:, bones] = h if all_set(mc) else np.where(mc[..., None], h, H0[:, bones])
            rot[:, bones] = rot[:, carriers]
            moved[:, bones] = mc
