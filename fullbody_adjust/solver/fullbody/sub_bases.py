"""Step 1 of Algorithm 1 (paper §5.2.1-5.2.2): where the SC and the root go, and the trunk solve that brings the
SC there (SubBasePlacement, mixed into adjust._Problem; it uses the problem's chains, targets, reach and
settings)."""

import numpy as np

from ..maths.geometry import all_set, any_set, norm
from ..obstacles.boxes import penetrations
from .reach_balls import nearest_in_balls, nearest_on_sphere_in_balls, sub_base_point, sub_base_point_in_plane
from .trunk_curl import curl_chord, curl_start

# The lean's radius is the chord of the curl toward the lean point, which moves a little with the radius: a few
# rounds settle both (the chord changes with the square of the bend, so each round shrinks the change).
_LEAN_ROUNDS = 3


class SubBasePlacement:
    """Where the sub-bases go, for frames `rows` of the problem (``p``: adjust._Problem, its chains, targets,
    reach and settings), the limbs solved by ``limbs`` (LimbPlacement) where the trunk needs them."""

    def __init__(self, problem, limbs):
        self.p = problem
        self.limbs = limbs

    def _upper(self):
        return [n for n, limb in self.p.model.limbs.items() if limb.hub == "sc"]

    def _legs(self):
        return [n for n in ("leg.L", "leg.R")]

    @staticmethod
    def _curl_shares(spine):
        """(b,m) how the trunk's curl shares a bend among the spine joints (b,n,3): in proportion to the square
        of each joint's lever to the SC. The lower joints move the SC farthest per degree, so they take most of
        a lean (the pelvis does not turn, and the lowest spine joint stands in for the hips); the upper ones
        keep the chest from pitching more than the lean needs."""
        return norm(spine[:, -1:] - spine[:, :-1]) ** 2

    def _balls(self, names, rows, offsets_from):
        """Reach balls for the sub-base `anchor`: a limb with base b (rigidly offset from the anchor by
        o = b - anchor) reaches its target t iff |anchor' - (t - o)| <= reach."""
        centres = np.stack([self.p.limb_target[n][rows] - offsets_from[n] for n in names], axis=1)
        radii = np.stack([self.p.reach_eff[n][rows] * (1.0 - self.p.settings.reach_margin) for n in names], axis=1)
        active = np.stack([self.p.limb_active[n][rows] for n in names], axis=1)
        prio = np.array([self.p.limb_priority[n] for n in names])
        return centres, radii, active, prio

    def _in_reach(self, names, rows, bases):
        """(b,) every active limb's target lies within its reach from `bases[name]` (rule (i), no margin beyond
        the tolerance that counts a target as met: a straight limb whose end is on its target is in reach, however
        its lengths' sum rounds)."""
        tol = self.p.settings.chain.tolerance
        ok = np.ones(len(rows), dtype=bool)
        for n in names:
            d = norm(self.p.limb_target[n][rows] - bases[n])
            ok &= ~self.p.limb_active[n][rows] | (d <= self.p.reach_eff[n][rows] + tol)
        return ok

    def _place_sc(self, rows, pref, trunk_base, offsets):
        """New SC for frames `rows`, from which every constrained upper limb reaches, in this order of
        preference (the first that exists wins):
          1. the trunk leans: the point nearest `pref` (b,3) at the chord of the trunk's curl toward it
             (fullbody/trunk_curl.py: the spine hardly shortens, its joints bend a few tens of degrees each, so pulling
             the SC straight toward the target would ask for a fold the joint limits refuse; and the chord
             starts at the SC's own distance, so the SC's target moves continuously from where it was);
          2. the trunk bends: nearest `pref` within the trunk's reach from `trunk_base`;
          3. from the arms' balls alone (the root will have to move), the variant deciding if they are
             disjoint. The root stays in cases 1-2.
        Returns (points (b,3), leaned (b,) bool: case 1)."""
        upper = self._upper()
        centres, radii, active, prio = self._balls(upper, rows, offsets)
        trunk_r = self.p.reach["trunk"][rows] * (1.0 - self.p.settings.reach_margin)
        spine = self.p.chain0["trunk"][rows]
        spine = spine + (trunk_base - spine[:, 0])[:, None, :]
        shares = self._curl_shares(spine)
        lean_r = norm(pref - trunk_base)
        for _ in range(_LEAN_ROUNDS):
            lean, ok_lean = nearest_on_sphere_in_balls(pref, trunk_base, lean_r, centres, radii, active)
            chord = curl_chord(spine, lean, shares)
            if np.array_equal(chord, lean_r):
                break  # settled: the rounds left and the placement below would repeat this one exactly
            lean_r = chord
        else:
            lean, ok_lean = nearest_on_sphere_in_balls(pref, trunk_base, lean_r, centres, radii, active)
        if all_set(ok_lean):
            return lean, ok_lean
        bend, ok_bend = nearest_in_balls(
            pref, np.concatenate([centres, trunk_base[:, None]], axis=1),
            np.concatenate([radii, trunk_r[:, None]], axis=1),
            np.concatenate([active, np.ones((len(rows), 1), dtype=bool)], axis=1))
        if all_set(ok_lean | ok_bend):
            return np.where(ok_lean[:, None], lean, bend), ok_lean
        arms_only, _ = sub_base_point(pref, centres, radii, active, prio, self.p.settings.variant)
        out = np.where(ok_bend[:, None], bend, arms_only)
        return np.where(ok_lean[:, None], lean, out), ok_lean

    def _across(self, rows):
        """(b,3) the unit normal of the plane the pelvis keeps to when it translates for the SC's sake, zero
        where it is free: the plane that holds the direction the upper limbs ask the SC to move in and lies
        square to the hips' line as far as that allows (its normal is the hips' line less its part along the
        ask). Each constrained upper limb whose target lies beyond its reach from its start base asks, toward
        its target, for how far it falls short (where the SC would go for it alone). A hand held where it stands
        asks nothing, though its reach ball may lean the SC sideways toward it: the trunk bends for that, and
        the pelvis does not slide along the hips, which would carry the knees sideways. A target out to the
        side asks along the hips' line, and the pelvis is free to follow it (no plane)."""
        ask = np.zeros((len(rows), 3))
        for n in self._upper():
            chain = self.p.chain0[n][rows]
            target = self.p.limb_target[n][rows]
            short = norm(target - chain[:, 0]) - self.p.reach_eff[n][rows]
            on = self.p.limb_active[n][rows] & (short > 0.0)
            # Toward the target from the joint its last two segments swing from (an arm's shoulder: a clavicle
            # rides on the chest and swings little, so a target straight in front of the shoulder asks for
            # straight ahead, not for the side the clavicle's base lies off).
            pull = target - chain[:, max(chain.shape[1] - 3, 0)]
            dist = norm(pull)
            on &= dist > 0.0
            ask += np.where(on[:, None], pull * (short / np.where(on, dist, 1.0))[:, None], 0.0)
        hips = self.p.chain0["leg.L"][rows, 0] - self.p.chain0["leg.R"][rows, 0]
        size = norm(ask)
        asked = size > 0.0
        along = ask / np.where(asked, size, 1.0)[:, None]
        normal = hips - (hips * along).sum(axis=1)[:, None] * along
        size = norm(normal)
        plane = asked & (size > 1e-9 * norm(hips))  # none without an ask, or for one along the hips' line
        return np.where(plane[:, None], normal / np.where(plane, size, 1.0)[:, None], 0.0)

    def _root_delta(self, rows, pref, trunk_centre, trunk_active, across=None):
        """Root translation for frames `rows`: nearest to `pref` (b,3) where every constrained foot reaches its
        target and (where trunk_active) the trunk reaches the SC target (trunk_centre = sc* - trunk base).
        across (b,3): where non-zero, the translation keeps to the plane through `pref` with that normal
        (_across) wherever the plane meets every ball (the trunk's only off the plane is one whose SC target
        lies farther to the side than the trunk reaches): the nearest such point, or the priorities' best
        effort in the plane. The trunk's curl takes the sideways part then, as far as it can."""
        legs = self._legs()
        hips = {n: self.p.chain0[n][rows, 0] for n in legs}
        centres, radii, active, prio = self._balls(legs, rows, hips)
        upper_prio = max([self.p.limb_priority[n] for n in self._upper()] + [0.0])
        centres = np.concatenate([centres, trunk_centre[:, None]], axis=1)
        radii = np.concatenate([radii, (self.p.reach["trunk"][rows] * (1.0 - self.p.settings.reach_margin))[:, None]], 1)
        active = np.concatenate([active, trunk_active[:, None]], axis=1)
        if self.p.settings.feet_first:
            prio = np.append(prio, -np.inf)  # ankle tasks first (variant 2 at the root)
            variant = "priority"
        else:
            prio = np.append(prio, upper_prio)
            variant = self.p.settings.variant
        use = np.zeros(len(rows), dtype=bool)
        if across is not None and any_set(across != 0.0):
            flat, _, meets = sub_base_point_in_plane(pref, across, centres, radii, active, prio, variant)
            use = (across != 0.0).any(axis=1) & meets
            if all_set(use):
                return flat
        delta, _ = sub_base_point(pref, centres, radii, active, prio, variant)
        return np.where(use[:, None], flat, delta) if any_set(use) else delta

    def _sub_bases(self, rows, offsets, force_sc=None):
        """Steps 1-2 for frames `rows`, with the upper limbs' base offsets from the SC `offsets[name]` (b,3);
        force_sc (b,) marks frames whose SC must move (a later pass: the turned offsets alone may look in
        reach, but only because the SC moved). Returns (delta, sc_star, trunk joints, trunk solved, trunk status,
        trunk reason)."""
        upper = self._upper()
        trunk0 = self.p.chain0["trunk"][rows]
        sc0, base0 = trunk0[:, -1], trunk0[:, 0]
        b = len(rows)
        any_upper = np.zeros(b, dtype=bool)
        for n in upper:
            any_upper |= self.p.limb_active[n][rows]

        # SC: stays exactly unless some constrained arm cannot reach from its current base (rule (i)).
        need_sc = ~self._in_reach(upper, rows, {n: sc0 + offsets[n] for n in upper})
        if force_sc is not None:
            need_sc |= force_sc
        # Placed only on the frames that need it (every step of a placement is row by row).
        sc_star = sc0.copy()
        leaned = np.zeros(b, dtype=bool)
        if any_set(need_sc):
            n = np.nonzero(need_sc)[0]
            sc_star[n], leaned[n] = self._place_sc(rows[n], sc0[n], base0[n], _rows_of(offsets, n))

        # Root: stays exactly while every constrained foot reaches from its hip and the trunk reaches sc*.
        legs = self._legs()
        trunk_ok = ~need_sc | (norm(sc_star - base0) <= self.p.reach["trunk"][rows])
        feet_reach = self._in_reach(legs, rows, {n: self.p.chain0[n][rows, 0] for n in legs})
        need_root = ~(feet_reach & trunk_ok)
        delta = np.zeros((b, 3))
        if any_set(need_root):
            n = np.nonzero(need_root)[0]
            # The feet that reach from their hips ask nothing of the root: it moves for the SC alone, and keeps
            # to the plane of the SC's ask (_across).
            across = np.where((need_sc & feet_reach)[n, None], self._across(rows[n]), 0.0)
            delta[n] = self._root_delta(rows[n], np.zeros((n.size, 3)), sc_star[n] - base0[n], need_sc[n], across)
        moved_root = (delta != 0.0).any(axis=1)

        # A root moved for the feet carries the SC along if the arms still reach from there; else the SC goes
        # to the nearest point (to where it was carried) from which they do.
        carried = ~need_sc & any_upper & moved_root
        if any_set(carried):
            sc_c = sc0 + delta
            need_c = carried & ~self._in_reach(upper, rows, {n: sc_c + offsets[n] for n in upper})
            if any_set(need_c):
                n = np.nonzero(need_c)[0]
                sc_star[n], leaned[n] = self._place_sc(rows[n], sc_c[n], base0[n] + delta[n], _rows_of(offsets, n))
                need_sc = need_sc | need_c

        # Trunk: FABRIK from the translated root to sc* where the SC moves relative to the root; else it rides.
        joints = trunk0 + delta[:, None, :]
        status = np.full(b, "", dtype=object)
        reason = np.full(b, "", dtype=object)
        solve = np.nonzero(need_sc)[0]
        if solve.size:
            # Where the trunk leans, from the curl that meets sc*: the chain solve has only the limits and the
            # obstacles left to settle. Where it must do more (sc* nearer its base, or the root moves), from the
            # start pose: curling there too left the hand farthest from a target out of reach farther still
            # (bench/fullbody.py, held-out dance clip).
            start = joints[solve].copy()
            lean = np.nonzero(leaned[solve])[0]
            if lean.size:
                start[lean] = curl_start(start[lean], sc_star[solve[lean]], self._curl_shares(start[lean]))
            res = self.limbs._solve("trunk", rows[solve], start, sc_star[solve])
            joints[solve] = res.positions
            status[solve] = res.status
            reason[solve] = res.reason
            # Paper §5.2.1: when the trunk cannot bring the SC there (joint limits), the pelvis moves by the
            # remaining error, as far as the feet allow, sideways too (the trunk's limits held it from taking
            # that part). Not past obstacles: a blocked trunk stays.
            err = sc_star[solve] - res.positions[:, -1]
            late = (norm(err) > self.p.settings.chain.tolerance) \
                & ((res.status == "limited") | (res.status == "max_iterations"))
            if any_set(late):
                s2 = solve[late]
                d2 = self._root_delta(rows[s2], delta[s2] + err[late], np.zeros((s2.size, 3)),
                                      np.zeros(s2.size, dtype=bool))
                shift = d2 - delta[s2]
                moved_chain = joints[s2] + shift[:, None, :]
                if self.p.obstacles is not None:
                    segs = np.stack([np.arange(joints.shape[1] - 1), np.arange(1, joints.shape[1])], axis=1)
                    boxes = self.p.obstacles.select(rows[s2])
                    before = sum(penetrations(joints[s2], segs, boxes))
                    after = sum(penetrations(moved_chain, segs, boxes))
                    keep = after <= before
                    shift = np.where(keep[:, None], shift, 0.0)
                    moved_chain = joints[s2] + shift[:, None, :]
                joints[s2] = moved_chain
                delta[s2] = delta[s2] + shift
                res_err = norm(sc_star[s2] - moved_chain[:, -1])
                fixed = res_err <= self.p.settings.chain.tolerance
                status[s2[fixed]] = "reached"
                reason[s2[fixed]] = "reached after the pelvis moved by the remaining error"
        return delta, sc_star, joints, need_sc, status, reason

    def _fixable(self, upper, offsets):
        """{upper limb: (F,) bool}: whether re-placing the SC could still bring the limb's target into reach.
        Turning the chest moves an arm base on a sphere of radius |offset| about the SC, the SC stays within
        the trunk's reach of the trunk base, and the trunk base moves with the root only where every
        constrained foot still reaches its target: a target no such trunk base puts within the sum of the
        three is out of reach however the chest turns. Two limbs whose targets are farther apart than their
        reaches and the (turn-invariant) distance between their bases cannot both reach: when the one the
        priorities keep (the higher, or the earlier on a tie) is out of reach itself, the one they drop cannot
        be helped either (while the kept one can reach, the passes still refine its placement). Such a limb
        is re-placed only while that can still gain more than the reach margin (adjust._Problem._solve_once)."""
        tol = self.p.settings.chain.tolerance
        base0 = self.p.chain0["trunk"][:, 0]
        legs = self._legs()
        # Where the trunk base may go: balls about each constrained ankle target, carried from hip to base.
        centres = [self.p.limb_target[n] - (self.p.chain0[n][:, 0] - base0) for n in legs]
        radii = [self.p.reach_eff[n] + tol for n in legs]
        active = [self.p.limb_active[n] for n in legs]
        alone = {}
        for n in upper:
            reach = self.p.reach["trunk"] + norm(offsets[n]) + self.p.reach_eff[n] + tol
            _, alone[n] = nearest_in_balls(base0, np.stack(centres + [self.p.limb_target[n]], axis=1),
                                           np.stack(radii + [reach], axis=1),
                                           np.stack(active + [self.p.limb_active[n]], axis=1))
        out = dict(alone)
        for i, a in enumerate(upper):
            for b in upper[i + 1:]:
                kept, dropped = (a, b) if self.p.limb_priority[b] <= self.p.limb_priority[a] else (b, a)
                apart = norm(self.p.limb_target[a] - self.p.limb_target[b]) > (
                    norm(offsets[a] - offsets[b]) + self.p.reach_eff[a] + self.p.reach_eff[b] + tol)
                out[dropped] = out[dropped] & ~(self.p.limb_active[kept] & ~alone[kept] & apart)
        return out


def _rows_of(per_limb, rows):
    """{limb: array} restricted to ``rows``."""
    return {name: value[rows] for name, value in per_limb.items()}
