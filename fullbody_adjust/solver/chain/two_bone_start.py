"""Warm start of a hinged limb (elbow, knee) before its chain solve: the last two segments placed by the
two-bone solution in the plane of the start hinge axis (see limb_placement.LimbPlacement._solve)."""

from ..maths import lanes
from ..maths import vectors as vec


def two_bone_start(start, targets, axis, pole=None):
    """Place the last two segments of chains (b,n,3) so the end meets `targets` (b,3) with the last joint's
    hinge (axis (b,3) at the start pose) bending to its positive side; where `pole` (b,3) is given (finite),
    the middle joint bends toward it instead, in the plane of the two segments' root, the target and the pole
    (as Blender's IK pole). Rigid turns only, smallest first:
      0. (chains with segments before the two, e.g. a clavicle) if the target is beyond the two segments'
         reach, turn the whole chain about joint 0 by the least angle that brings it within reach;
      1. swing the two segments about their root (shoulder/hip) so the end points at the target;
      2. turn the upper segment about the hinge axis (made perpendicular to root -> target) so the end lies
         at the target's distance (law of cosines; out-of-range distances are clamped: FABRIK reports them).
    Each chain is solved on its own (maths/lanes.py: a chain alone gets its row's bits)."""
    return lanes.run(_two_bone_start, (start, targets, axis, pole))


def _two_bone_start(chain, target, axis, pole):
    m = len(chain) - 1
    a = vec.norm(vec.sub(chain[m - 1], chain[m - 2]))
    c = vec.norm(vec.sub(chain[m], chain[m - 1]))
    if m >= 3:
        chain, axis = _within_reach(chain, target, axis, a, c, m)
    pivot = chain[m - 2]
    turn = vec.swing_rotation(vec.sub(chain[m], pivot), vec.sub(target, pivot))
    chain = chain[:m - 2] + [vec.add(pivot, vec.apply_matrix(turn, vec.sub(p, pivot))) for p in chain[m - 2:]]
    axis = vec.apply_matrix(turn, axis)
    to_target = vec.sub(target, pivot)
    dist = vec.norm(to_target)
    d = lanes.clip(dist, abs(a - c), a + c)
    dt = vec.divided(to_target, lanes.maximum(dist, 1e-300))
    given = False if pole is None else lanes.isfinite(pole[..., 0] if lanes.many(pole) else pole[0])
    if lanes.any_(given):
        # The elbow lands at cos(alpha) dt + sin(alpha) (dt x n): toward the pole's side when n = w x dt.
        toward = vec.cross(lanes.pick(given, vec.sub(pole, pivot), (0.0, 0.0, 0.0)), dt)
        use = given & (vec.norm(toward) > 1e-9 * lanes.maximum(dist, 1e-300))
        axis = lanes.pick(use, toward, axis)
    n = vec.sub(axis, vec.scaled(dt, vec.dot(axis, dt)))
    n_len = vec.norm(n)
    ok = n_len > 1e-9
    # A chain without a bend plane keeps its start (below); any unit axis lets the calculation go on.
    n = lanes.pick(ok, vec.divided(n, lanes.where(ok, n_len, 1.0)), vec.EYE[0])
    cos_alpha = lanes.clip(lanes.divide(a * a + d * d - c * c, 2.0 * a * lanes.maximum(d, 1e-300)), -1.0, 1.0)
    # Upper segment at -alpha from root -> target about n, so the lower one bends by a positive angle.
    upper = vec.rotate_about_axis(dt, n, -lanes.arccos(cos_alpha))
    elbow = vec.add(pivot, vec.scaled(upper, a))
    lower = vec.sub(target, elbow)
    ln = vec.norm(lower)
    lower = lanes.pick(ln > 1e-300, vec.divided(lower, lanes.maximum(ln, 1e-300)), upper)
    good = ok & (dist > 0.0)
    placed = (elbow, vec.add(elbow, vec.scaled(lower, c)))
    return chain[:m - 1] + [lanes.pick(good, p, q) for p, q in zip(placed, chain[m - 1:])]


def _within_reach(chain, target, axis, a, c, m):
    """Step 0: the chain turned about joint 0 as one rigid piece (and its hinge axis with it) by the least angle
    that brings the target within the two segments' reach, where it is beyond it."""
    base = chain[0]
    arm = vec.sub(chain[m - 2], base)  # joint 0 -> root of the two segments
    length = vec.norm(arm)
    to_t = vec.sub(target, base)
    dist = vec.norm(to_t)
    far = lanes.maximum(dist, 1e-300)
    reach2 = (a + c) * (1.0 - 1e-3)
    # Pivot p = base + length * w is within reach2 of the target iff w . t_dir >= cos_max.
    cos_max = lanes.divide(dist * dist + length * length - reach2 * reach2, 2.0 * length * far)
    cos_now = lanes.divide(vec.dot(arm, to_t), length * far)
    need = (cos_now < cos_max) & (dist > 0.0)
    if not lanes.any_(need):
        return chain, axis
    t_dir = vec.divided(to_t, far)
    angle_now = lanes.arccos(lanes.clip(cos_now, -1.0, 1.0))
    angle_ok = lanes.arccos(lanes.clip(cos_max, -1.0, 1.0))
    side = vec.cross(t_dir, arm)
    flip = lanes.where(vec.norm(side) <= 1e-12, 1.0, 0.0)
    # Rows that need no turn get a harmless one, thrown away below (they raise nothing a chain alone would not).
    about = lanes.pick(need, vec.add(side, vec.scaled(vec.any_perpendicular(t_dir), flip)), vec.EYE[0])
    new_w = vec.rotate_about_axis(t_dir, about, angle_ok)
    turn = vec.swing_rotation(lanes.pick(need, arm, vec.EYE[0]),
                              lanes.pick(need & (angle_now > angle_ok), new_w, lanes.pick(need, arm, vec.EYE[0])))
    turned = [vec.add(base, vec.apply_matrix(turn, vec.sub(p, base))) for p in chain]
    axis = lanes.pick(need, vec.apply_matrix(turn, axis), axis)
    return [lanes.pick(need, t, p) for t, p in zip(turned, chain)], axis
