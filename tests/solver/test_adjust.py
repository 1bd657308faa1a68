"""Full-body adjustment (paper §5, Algorithm 1) on a CMU skeleton and a synthetic one.

Every expectation is computed here from the skeleton's own geometry (limb reach, ball distances)."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fullbody_adjust.solver.fullbody.adjust import (AdjustSettings, adjust_frames, adjust_pose, nearest_in_balls,
                                           project_onto_balls, sub_base_point)
from fullbody_adjust.solver.body.model import END, BodyModel
from fullbody_adjust.solver.limits.human import default_limits
from fullbody_adjust.solver.errors import SolverInputError
from fullbody_adjust.solver.maths.geometry import swing_rotation
from fullbody_adjust.solver.limits.joint_limits import CONE, HINGE
from fullbody_adjust.solver.obstacles.boxes import Boxes, points_inside, segments_cross
from tests.helpers.bvh import CMU_GROUPS, read_cmu

EFFECTORS = ("hand.L", "hand.R", "foot.L", "foot.R")
TOL = AdjustSettings().chain.tolerance
NAN3 = np.full(3, np.nan)


# ---------------------------------------------------------------------------------------------------------
# Skeletons


def synthetic_humanoid():
    """A small Blender-like rig (Z up, facing -Y), bones not all connected (clavicle -> upper arm is not, as in
    Rigify), pelvis side bones between root and thighs, fingers and toes as plain children."""
    bones = []  # (name, parent name, head, tail)

    def add(name, parent, head, tail):
        bones.append((name, parent, np.array(head, float), np.array(tail, float)))

    add("pelvis", None, (0, 0, 1.0), (0, 0, 1.1))
    add("spine", "pelvis", (0, 0, 1.0), (0, 0.01, 1.2))
    add("chest", "spine", (0, 0.01, 1.2), (0, 0, 1.42))
    add("neck", "chest", (0, 0, 1.42), (0, -0.01, 1.52))
    add("head", "neck", (0, -0.01, 1.52), (0, -0.01, 1.72))
    for s, x in (("L", 1.0), ("R", -1.0)):
        add(f"clavicle.{s}", "chest", (0.02 * x, -0.02, 1.38), (0.17 * x, 0.0, 1.38))
        add(f"upper_arm.{s}", f"clavicle.{s}", (0.19 * x, 0.0, 1.37), (0.21 * x, 0.02, 1.1))
        add(f"forearm.{s}", f"upper_arm.{s}", (0.21 * x, 0.02, 1.1), (0.22 * x, -0.12, 0.88))
        add(f"hand.{s}", f"forearm.{s}", (0.22 * x, -0.12, 0.88), (0.22 * x, -0.15, 0.8))
        add(f"finger.{s}", f"hand.{s}", (0.22 * x, -0.15, 0.8), (0.22 * x, -0.17, 0.76))
        add(f"hip.{s}", "pelvis", (0.0, 0.0, 1.0), (0.1 * x, 0.0, 0.95))
        add(f"thigh.{s}", f"hip.{s}", (0.1 * x, 0.0, 0.95), (0.1 * x, -0.04, 0.52))
        add(f"shin.{s}", f"thigh.{s}", (0.1 * x, -0.04, 0.52), (0.1 * x, 0.0, 0.08))
        add(f"foot.{s}", f"shin.{s}", (0.1 * x, 0.0, 0.08), (0.1 * x, -0.12, 0.0))
        add(f"toe.{s}", f"foot.{s}", (0.1 * x, -0.12, 0.0), (0.1 * x, -0.18, 0.0))
    names = [b[0] for b in bones]
    parents = [-1 if b[1] is None else names.index(b[1]) for b in bones]
    groups = {"root": ["pelvis"], "trunk": ["spine", "chest"], "head": ["neck", "head"]}
    for s in "LR":
        groups.update({f"arm.{s}": [f"clavicle.{s}", f"upper_arm.{s}", f"forearm.{s}"], f"hand.{s}": [f"hand.{s}"],
                       f"leg.{s}": [f"thigh.{s}", f"shin.{s}"], f"foot.{s}": [f"foot.{s}"]})
    model = BodyModel.from_description(names, parents, groups)
    heads = np.array([b[2] for b in bones])[None]
    tails = np.array([b[3] for b in bones])[None]
    return model, heads, tails


@pytest.fixture(scope="module")
def synth():
    return synthetic_humanoid()


@pytest.fixture(scope="module", params=["synthetic", "cmu"])
def rig(request):
    """One standing pose: the synthetic rig, or frame 100 of the CMU walk (Y up, Blender-import bones)."""
    if request.param == "synthetic":
        return synthetic_humanoid()
    clip = read_cmu("cmu_07_01_walk.bvh")
    heads, tails = clip.bones([100])
    return BodyModel.from_description(clip.names, clip.parents, CMU_GROUPS), heads, tails


@pytest.fixture(scope="module")
def pickup():
    clip = read_cmu("cmu_02_06_pickup_f0-1349.bvh")
    model = BodyModel.from_description(clip.names, clip.parents, CMU_GROUPS)
    return clip, model


def _joints(model, heads, tails, limb):
    return model.limbs[limb].joints(heads, tails)


def _reach(model, heads, tails, limb):
    j = _joints(model, heads, tails, limb)
    return np.linalg.norm(np.diff(j, axis=-2), axis=-1).sum(axis=-1)


def _descendants(model, roots):
    out = set(roots)
    changed = True
    while changed:
        changed = False
        for j, p in enumerate(model.parents):
            if p in out and j not in out:
                out.add(j)
                changed = True
    return out


def _moved_groups(model, h, t, res):
    """The groups any of whose bones' heads or tails moved on frame 0."""
    return {g for g, bones in model.groups.items()
            if bones and ((res.heads[0, bones] != h[0, bones]) | (res.tails[0, bones] != t[0, bones])).any()}


def _targets(model, heads, tails, **given):
    """(F,4,3) targets for EFFECTORS: the given ones (F,3) or (3,), NaN for the others."""
    f = heads.shape[0]
    out = np.full((f, len(EFFECTORS), 3), np.nan)
    for k, e in enumerate(EFFECTORS):
        if e in given:
            out[:, k] = given[e]
    return out


def _current(model, heads, effector):
    limb = {"hand.L": "arm.L", "hand.R": "arm.R", "foot.L": "leg.L", "foot.R": "leg.R"}[effector]
    return heads[:, model.limbs[limb].end_bone]


def _check_rigid_output(model, heads0, tails0, res):
    """Bone lengths kept; every bone's new vector = R @ old vector; R proper rotations; non-chain bones keep
    their parent's rotation (local transform kept)."""
    old = tails0 - heads0
    new = res.tails - res.heads
    np.testing.assert_allclose(np.linalg.norm(new, axis=-1), np.linalg.norm(old, axis=-1), rtol=1e-9)
    np.testing.assert_allclose(np.einsum("fjab,fjb->fja", res.rotations, old), new, atol=1e-9)
    r = res.rotations
    np.testing.assert_allclose(np.einsum("fjab,fjcb->fjac", r, r), np.broadcast_to(np.eye(3), r.shape), atol=1e-9)
    np.testing.assert_allclose(np.linalg.det(r), 1.0, atol=1e-9)
    chain_bones = {b for limb in model.limbs.values() for b in limb.bones} | {model.root}
    for j, p in enumerate(model.parents):
        if p >= 0 and j not in chain_bones and model.roles[j] != END:  # hands, feet, head ends
            np.testing.assert_allclose(r[:, j], r[:, p], atol=1e-12)
            np.testing.assert_allclose(res.heads[:, j] - res.heads[:, p],
                                       np.einsum("fab,fb->fa", r[:, p], heads0[:, j] - heads0[:, p]), atol=1e-9)


# ---------------------------------------------------------------------------------------------------------
# Sub-base geometry


def _dykstra(p, centres, radii, iterations=4000):
    """Reference projection onto an intersection of balls (Dykstra's algorithm, slow but simple)."""
    x = p.copy()
    incr = np.zeros((len(radii), 3))
    for _ in range(iterations):
        for k in range(len(radii)):
            y = x + incr[k]
            d = y - centres[k]
            n = np.linalg.norm(d)
            z = centres[k] + d * (radii[k] / n) if n > radii[k] else y
            incr[k] = y - z
            x = z
    return x


@settings(deadline=None, max_examples=60)
@given(st.integers(0, 2**31 - 1), st.integers(1, 3))
def test_nearest_point_of_intersecting_balls_matches_dykstra(seed, k):
    rng = np.random.default_rng(seed)
    centres = rng.normal(size=(k, 3))
    common = rng.normal(size=3) * 0.3  # a point every ball contains, so the intersection is not empty
    radii = np.linalg.norm(centres - common, axis=1) + rng.uniform(0.01, 0.6, size=k)
    p = rng.normal(size=3) * 2.5
    x, ok = nearest_in_balls(p[None], centres[None], radii[None], np.ones((1, k), bool))
    assert ok[0]
    assert np.all(np.linalg.norm(x[0] - centres, axis=1) <= radii * (1 + 1e-9))
    ref = _dykstra(p, centres, radii)
    assert np.linalg.norm(x[0] - p) <= np.linalg.norm(ref - p) + 1e-9
    np.testing.assert_allclose(x[0], ref, atol=1e-5)


def test_point_inside_every_ball_is_returned_bit_exact():
    p = np.array([[0.1, 0.2, 0.3]])
    x, ok = nearest_in_balls(p, np.zeros((1, 2, 3)), np.array([[1.0, 2.0]]), np.ones((1, 2), bool))
    assert ok[0] and np.array_equal(x, p)


def test_priority_variants_on_disjoint_balls():
    """Two balls that do not meet: variant 1 (eq. 4) = priority-weighted mean of the proposals; plain FABRIK's
    centroid = their plain mean; variant 2 = inside the higher-priority ball, as near the other as it gets."""
    p = np.array([[0.0, 1.0, 0.0]])
    centres = np.array([[[-2.0, 0.0, 0.0], [2.0, 0.0, 0.0]]])
    radii = np.array([[1.0, 1.0]])
    active = np.ones((1, 2), bool)
    prio = np.array([3.0, 1.0])
    proposals = project_onto_balls(p, centres, radii)[0]
    x1, ok = sub_base_point(p, centres, radii, active, prio, "weighted")
    assert not ok[0]
    np.testing.assert_allclose(x1[0], (3 * proposals[0] + proposals[1]) / 4, atol=1e-12)
    x0, _ = sub_base_point(p, centres, radii, active, prio, "fabrik")
    np.testing.assert_allclose(x0[0], proposals.mean(axis=0), atol=1e-12)
    x2, _ = sub_base_point(p, centres, radii, active, prio, "priority")
    # Ball 0 (priority 3) is served: x2 is on it, at its point nearest ball 1's proposal.
    want = centres[0, 0] + (proposals[1] - centres[0, 0]) / np.linalg.norm(proposals[1] - centres[0, 0])
    np.testing.assert_allclose(x2[0], want, atol=1e-12)
    x2r, _ = sub_base_point(p, centres, radii, active, prio[::-1], "priority")
    assert np.linalg.norm(x2r[0] - centres[0, 1]) <= 1.0 + 1e-12


# ---------------------------------------------------------------------------------------------------------
# Rule (i): a limb alone serves when its target is within reach


def test_near_target_moves_only_that_arm(rig):
    model, h, t = rig
    wrist = _current(model, h, "hand.L")
    up, left, forward = (v[0] for v in model.body_frame(h, t))
    target = wrist + 0.08 * forward + 0.08 * up + 0.03 * left  # a hand raised a little to the front
    base = _joints(model, h, t, "arm.L")[:, 0]
    assert np.linalg.norm(target - base) < _reach(model, h, t, "arm.L")[0]  # within the arm's reach
    res = adjust_frames(model, h, t, _targets(model, h, t, **{"hand.L": target}), EFFECTORS)
    assert res.sc_displacement[0] == 0.0 and res.root_displacement[0] == 0.0
    assert res.status[0, 0] == "reached" and res.residuals[0, 0] <= TOL
    assert list(res.status[0, 1:]) == ["unconstrained"] * 3 and np.all(np.isnan(res.residuals[0, 1:]))
    moving = _descendants(model, [model.groups["arm.L"][0]])
    still = [j for j in range(len(model.names)) if j not in moving]
    assert np.array_equal(res.heads[:, still], h[:, still]) and np.array_equal(res.tails[:, still], t[:, still])
    assert _moved_groups(model, h, t, res) == {"arm.L", "hand.L"}
    # The hand keeps its world orientation; the finger rides along with it.
    hand = model.groups["hand.L"][0]
    np.testing.assert_array_equal(res.rotations[0, hand], np.eye(3))
    _check_rigid_output(model, h, t, res)


def test_near_targets_on_captured_poses_leave_sc_and_root_exactly(pickup):
    """Targets = each frame's own wrists and ankles nudged by up to 4 cm, kept within reach: every frame keeps
    its SC and root bit-exact, whatever the limbs do."""
    clip, model = pickup
    rng = np.random.default_rng(7)
    frames = rng.choice(np.arange(1, clip.frame_count), 24, replace=False)
    h, t = clip.bones(frames)
    tg = np.stack([_current(model, h, e) for e in EFFECTORS], axis=1) + rng.uniform(-0.04, 0.04, (24, 4, 3))
    for k, limb in enumerate(("arm.L", "arm.R", "leg.L", "leg.R")):
        base = _joints(model, h, t, limb)[:, 0]
        reach = _reach(model, h, t, limb)
        d = np.linalg.norm(tg[:, k] - base, axis=1)
        scale = np.minimum(1.0, 0.98 * reach / d)  # pull nearly straight legs' targets back within reach
        tg[:, k] = base + (tg[:, k] - base) * scale[:, None]
        assert np.all(np.linalg.norm(tg[:, k] - base, axis=1) <= reach)
    res = adjust_frames(model, h, t, tg, EFFECTORS)
    assert np.all(res.sc_displacement == 0.0) and np.all(res.root_displacement == 0.0)
    trunk = model.groups["trunk"] + model.groups["root"]
    assert np.array_equal(res.heads[:, trunk], h[:, trunk])
    assert np.mean(res.status == "reached") > 0.9
    assert set(np.unique(res.status)) <= {"reached", "limited"}  # short only where a joint limit held
    _check_rigid_output(model, h, t, res)


# ---------------------------------------------------------------------------------------------------------
# Rule (ii): far -> the trunk bends; very far -> the pelvis translates


def _forward_down(model, h, t):
    up, left, forward = model.body_frame(h, t)
    d = forward[0] - 0.8 * up[0]
    return d / np.linalg.norm(d)


def test_far_target_bends_the_trunk_and_keeps_the_root(rig):
    model, h, t = rig
    base = _joints(model, h, t, "arm.L")[0, 0]
    reach = _reach(model, h, t, "arm.L")[0]
    target = base + _forward_down(model, h, t) * (reach + 0.15)  # 15 cm beyond the arm alone
    res = adjust_frames(model, h, t, _targets(model, h, t, **{"hand.L": target}), EFFECTORS)
    assert res.status[0, 0] == "reached" and res.residuals[0, 0] <= TOL
    assert res.root_displacement[0] == 0.0
    # The SC had to come at least 15 cm closer to the target, and it stays within the trunk's reach.
    assert res.sc_displacement[0] >= 0.15 * 0.99
    trunk_base = _joints(model, h, t, "trunk")[0, 0]
    new_sc = _joints(model, res.heads, res.tails, "trunk")[0, -1]
    assert np.linalg.norm(new_sc - trunk_base) <= _reach(model, h, t, "trunk")[0] + 1e-9
    moved = _moved_groups(model, h, t, res)
    assert "trunk" in moved and not moved & {"root", "leg.L", "leg.R"}
    _check_rigid_output(model, h, t, res)


def test_very_far_target_translates_the_root(rig):
    model, h, t = rig
    trunk = _joints(model, h, t, "trunk")[0]
    base = _joints(model, h, t, "arm.L")[0, 0]
    arm_reach = _reach(model, h, t, "arm.L")[0]
    trunk_reach = _reach(model, h, t, "trunk")[0]
    sc_to_base = np.linalg.norm(base - trunk[-1])
    d = _forward_down(model, h, t)
    far = trunk_reach + sc_to_base + arm_reach + 0.3  # beyond anything the upper body can do from the root
    target = trunk[0] + d * far
    res = adjust_frames(model, h, t, _targets(model, h, t, **{"hand.L": target}), EFFECTORS)
    assert res.status[0, 0] == "reached" and res.residuals[0, 0] <= TOL
    assert res.root_displacement[0] >= 0.3 * 0.99
    # Legs are unconstrained: they ride along with the pelvis.
    for limb in ("leg.L", "leg.R"):
        np.testing.assert_allclose(_joints(model, res.heads, res.tails, limb) - _joints(model, h, t, limb),
                                   np.broadcast_to(res.heads[:, model.root] - h[:, model.root], (1, 3, 3)),
                                   atol=1e-12)


def test_feet_at_their_ankles_stay_met_while_the_hand_reaches_far(rig):
    model, h, t = rig
    trunk = _joints(model, h, t, "trunk")[0]
    upper_body = _reach(model, h, t, "trunk")[0] + np.linalg.norm(_joints(model, h, t, "arm.L")[0, 0] - trunk[-1]) \
        + _reach(model, h, t, "arm.L")[0]
    target = trunk[0] + _forward_down(model, h, t) * (upper_body + 0.1)  # the pelvis has to come 10 cm closer
    ankles = {e: _current(model, h, e) for e in ("foot.L", "foot.R")}
    res = adjust_frames(model, h, t, _targets(model, h, t, **{"hand.L": target}, **ankles), EFFECTORS)
    assert np.all(res.residuals[0, [0, 2, 3]] <= TOL), res.status
    assert res.root_displacement[0] >= 0.1 * 0.99  # the pelvis helped (the knees bend)...
    for e in ("foot.L", "foot.R"):  # ...and the feet did not move at all beyond tolerance
        assert np.linalg.norm(res.heads[0, model.groups[e][0]] - ankles[e][0]) <= TOL


def test_root_moved_for_the_feet_carries_the_upper_body_when_the_hands_still_reach(rig):
    """Ankle targets 4 cm beyond the legs' reach (pushed out along hip -> ankle): the pelvis must follow. The
    hands, held at their current places, still reach from the carried chest, so the trunk rides along unbent."""
    model, h, t = rig
    feet = {}
    for limb, e in (("leg.L", "foot.L"), ("leg.R", "foot.R")):
        hip = _joints(model, h, t, limb)[:, 0]
        out = _current(model, h, e) - hip
        feet[e] = hip + out / np.linalg.norm(out) * (_reach(model, h, t, limb)[0] + 0.04)
    for limb, e in (("leg.L", "foot.L"), ("leg.R", "foot.R")):
        assert np.linalg.norm(feet[e][0] - _joints(model, h, t, limb)[0, 0]) > _reach(model, h, t, limb)[0]
    hands = {e: _current(model, h, e) for e in ("hand.L", "hand.R")}
    res = adjust_frames(model, h, t, _targets(model, h, t, **hands, **feet), EFFECTORS)
    assert np.all(res.residuals[0] <= TOL), res.reasons
    assert res.root_displacement[0] > 0.0
    np.testing.assert_allclose(res.sc_displacement[0], res.root_displacement[0], rtol=1e-12)
    for b in model.groups["trunk"]:
        np.testing.assert_array_equal(res.rotations[0, b], np.eye(3))


def test_feet_outrank_an_unreachable_hand(rig):
    """Ankle tasks have the highest priority at the root: a hand target out of the body's reach with feet
    planted leaves the feet met and the hand short ('unreachable'); the root stays where the legs reach."""
    model, h, t = rig
    ankles = {e: _current(model, h, e) for e in ("foot.L", "foot.R")}
    target = _joints(model, h, t, "trunk")[0, -1] + 3.0 * model.body_frame(h, t)[2][0]  # 3 m in front of the chest
    res = adjust_frames(model, h, t, _targets(model, h, t, **{"hand.L": target}, **ankles), EFFECTORS)
    assert res.status[0, 0] == "unreachable" and res.residuals[0, 0] > 1.0
    assert np.all(res.residuals[0, 2:] <= TOL)
    for limb, e in (("leg.L", "foot.L"), ("leg.R", "foot.R")):
        hip = _joints(model, res.heads, res.tails, limb)[0, 0]
        assert np.linalg.norm(ankles[e][0] - hip) <= _reach(model, h, t, limb)[0] + 1e-9


def test_feet_held_while_hands_reach_on_captured_poses(pickup):
    """Pick-up clip: targets = wrists 40 frames later and the ankles where they are now."""
    clip, model = pickup
    frames = np.arange(200, 1300, 100)
    h, t = clip.bones(frames)
    later, _ = clip.bones(frames + 40)
    tg = np.stack([_current(model, later, "hand.L"), _current(model, later, "hand.R"),
                   _current(model, h, "foot.L"), _current(model, h, "foot.R")], axis=1)
    res = adjust_frames(model, h, t, tg, EFFECTORS)
    assert np.all(res.residuals[:, 2:] <= TOL)
    assert np.mean(res.residuals[:, :2] <= TOL) >= 0.8
    _check_rigid_output(model, h, t, res)


# ---------------------------------------------------------------------------------------------------------
# Variants at the SC (paper §4.2)


def test_variant_2_meets_the_high_priority_hand_variant_1_compromises(rig):
    model, h, t = rig
    sc = _joints(model, h, t, "trunk")[0, -1]
    # Hands pulled 1.2 m apart to either side, further than the arms' balls overlap.
    _, left, _ = model.body_frame(h, t)
    tl, tr = sc + 1.0 * left[0], sc - 1.0 * left[0]
    tg = _targets(model, h, t, **{"hand.L": tl, "hand.R": tr})
    prio = np.array([3.0, 1.0, 1.0, 1.0])
    v2 = adjust_frames(model, h, t, tg, EFFECTORS, prio, settings=AdjustSettings(variant="priority"))
    v1 = adjust_frames(model, h, t, tg, EFFECTORS, prio, settings=AdjustSettings(variant="weighted"))
    v0 = adjust_frames(model, h, t, tg, EFFECTORS, prio, settings=AdjustSettings(variant="fabrik"))
    assert v2.residuals[0, 0] <= TOL and v2.residuals[0, 1] > 0.05  # high priority met, the other best effort
    assert v1.residuals[0, 0] > TOL and v1.residuals[0, 1] > TOL  # neither fully met...
    assert v1.residuals[0, 0] < v1.residuals[0, 1]  # ...but weighted toward the higher priority
    assert v1.residuals[0, 1] < v2.residuals[0, 1]  # and the low priority one does better than under variant 2
    assert abs(v0.residuals[0, 0] - v0.residuals[0, 1]) < abs(v1.residuals[0, 0] - v1.residuals[0, 1])


# ---------------------------------------------------------------------------------------------------------
# Obstacles and joint limits in every group


def _penetrations(model, heads, tails, limb, boxes, target):
    j = _joints(model, heads, tails, limb)[0]
    inside = points_inside(j[1:], boxes).any(axis=-1)
    crossing = segments_cross(j[:-1], j[1:], boxes).any(axis=-1)
    assert not points_inside(target, boxes).any()
    return int(inside.sum() + crossing.sum())


@pytest.mark.parametrize("limb, effector, use_limits", [
    ("arm.L", "hand.L", True), ("trunk", "hand.L", True), ("leg.L", "foot.L", True), ("leg.L", "foot.L", False)])
def test_obstacles_are_avoided_in_every_group(synth, limb, effector, use_limits):
    """Solve once free; put a 4 cm box where the group's middle joint went; solve again: the group's joints and
    segments stay out of the box, and the task is met or honestly reported 'blocked'. (A hinged knee goes
    around a box at the knee by turning its bend plane about the thigh, within the knee's twist range.)"""
    model, h, t = synth
    if limb == "trunk":
        base = _joints(model, h, t, "arm.L")[0, 0]
        target = base + _forward_down(model, h, t) * (_reach(model, h, t, "arm.L")[0] + 0.15)
        tg = _targets(model, h, t, **{"hand.L": target})
    elif limb == "arm.L":
        target = _current(model, h, "hand.L")[0] + np.array([0.1, -0.25, 0.15])
        tg = _targets(model, h, t, **{"hand.L": target})
    else:
        target = _current(model, h, "foot.L")[0] + np.array([0.05, -0.25, 0.2])
        tg = _targets(model, h, t, **{"foot.L": target})
    cfg = AdjustSettings(use_limits=use_limits)
    free = adjust_frames(model, h, t, tg, EFFECTORS, settings=cfg)
    k = EFFECTORS.index(effector)
    assert free.residuals[0, k] <= TOL
    joints = _joints(model, free.heads, free.tails, limb)[0]
    mid = joints[len(joints) // 2]
    boxes = Boxes(mid[None] - 0.02, mid[None] + 0.02)
    assert _penetrations(model, free.heads, free.tails, limb, boxes, target) > 0
    res = adjust_frames(model, h, t, tg, EFFECTORS, obstacles=boxes, settings=cfg)
    assert _penetrations(model, res.heads, res.tails, limb, boxes, target) == 0
    if limb == "leg.L" and not use_limits:
        # Knee inside the box, no limits: the chain solver's obstacle response may stall (FABRIK keeps the knee
        # near its old side). Either way: no penetration, and a task not met says why.
        assert res.residuals[0, k] <= TOL or (res.status[0, k] == "blocked" and "obstacle" in res.reasons[0, k])
    else:
        assert res.residuals[0, k] <= TOL, res.reasons[0, k]
    if use_limits:
        _assert_limits_hold(model, h, t, res, default_limits(model, h, t))


def test_blocked_target_is_reported(synth):
    model, h, t = synth
    wrist = _current(model, h, "hand.L")[0]
    target = wrist + np.array([0.0, -0.3, 0.0])
    # A wall between the wrist and the target, too large to go around within the arm's reach.
    boxes = Boxes(np.array([[-2.0, wrist[1] - 0.18, -2.0]]), np.array([[2.0, wrist[1] - 0.12, 4.0]]))
    res = adjust_frames(model, h, t, _targets(model, h, t, **{"hand.L": target}), EFFECTORS, obstacles=boxes)
    assert res.status[0, 0] == "blocked" and res.residuals[0, 0] > TOL


def _assert_limits_hold(model, h, t, res, limits):
    """Cones measured on the result against their parent directions (carried by the parent's rotation);
    hinges: the bend stays within the range's magnitude and on the natural side of the start's hinge."""
    for name, limb in model.limbs.items():
        ll = limits[name]
        j = _joints(model, res.heads, res.tails, name)
        segs = np.diff(j, axis=1)
        parent_rot = res.rotations[:, model.parents[limb.bones[0]]]
        for i, kind in enumerate(ll.limits.kind):
            if i == 0:
                parent = np.einsum("fab,fb->fa", parent_rot, ll.parent_direction)
            else:
                parent = segs[:, i - 1]
            u = parent / np.linalg.norm(parent, axis=1, keepdims=True)
            v = segs[:, i] / np.linalg.norm(segs[:, i], axis=1, keepdims=True)
            angle = np.arccos(np.clip(np.sum(u * v, axis=1), -1, 1))
            if kind == CONE:
                assert np.all(angle <= ll.limits.cone_angle[i] + 1e-6), (name, i, angle)
            elif kind == HINGE:
                assert np.all(angle <= ll.limits.hinge_max[i] + 1e-6), (name, i)
                # natural side: the start axis carried by the upper segment's own rotation
                axis = np.einsum("fab,fb->fa", res.rotations[:, limb.bones[i - 1]], ll.limits.hinge_axis[:, i])
                side = np.sum(np.cross(u, v) * axis, axis=1)
                assert np.all((side >= -np.sin(-ll.limits.hinge_min[i]) - 1e-6) | (angle < 0.05)), (name, side)


def test_joint_limits_hold_in_every_group(pickup):
    clip, model = pickup
    frames = np.arange(100, 1300, 60)
    h, t = clip.bones(frames)
    later, _ = clip.bones(frames + 45)
    tg = np.stack([_current(model, later, e) for e in EFFECTORS], axis=1)
    tg = tg - later[:, None, model.root] + h[:, None, model.root]  # same pelvis position, another posture
    res = adjust_frames(model, h, t, tg, EFFECTORS)
    assert np.any(res.sc_displacement > 0) and np.mean(res.status == "reached") > 0.8
    _assert_limits_hold(model, h, t, res, default_limits(model, h, t))
    # Captured targets are reachable within the limits: (nearly) all met, as without limits.
    free = adjust_frames(model, h, t, tg, EFFECTORS, settings=AdjustSettings(use_limits=False))
    assert np.mean(res.status == "reached") >= 0.95 and np.mean(free.status == "reached") >= 0.95


def test_a_limb_held_short_by_its_limits_gets_help_from_the_trunk(pickup):
    """Captured wrists and ankles from 60 frames later (pelvis kept): some lie within the arm's length but past
    what its limits let it reach from the unmoved chest. Read literally (help_held_limbs=False) rule (i) keeps the
    SC and the task ends 'limited'; by default the SC moves and the task is met. Where every limb reaches alone,
    both readings give the very same pose: the SC and root untouched."""
    clip, model = pickup
    frames = np.arange(61, clip.frame_count - 1, 10)
    h, t = clip.bones(frames)
    h0, t0 = clip.bones(frames - 60)
    shift = (h[:, model.root] - h0[:, model.root])[:, None]
    h0, t0 = h0 + shift, t0 + shift
    tg = np.stack([_current(model, h, e) for e in EFFECTORS], axis=1)
    strict = adjust_frames(model, h0, t0, tg, EFFECTORS, settings=AdjustSettings(help_held_limbs=False))
    helped = adjust_frames(model, h0, t0, tg, EFFECTORS)

    held = strict.status == "limited"
    rows = np.nonzero(held.any(axis=1))[0]
    assert rows.size > 0 and np.all(strict.sc_displacement[rows] + strict.root_displacement[rows] == 0.0)
    assert np.mean(helped.status[held] == "reached") >= 0.9
    assert np.all(helped.sc_displacement[rows] + helped.root_displacement[rows] > 0.0)

    alone = np.all(strict.status == "reached", axis=1)
    assert alone.sum() > 0.8 * len(frames)
    np.testing.assert_array_equal(helped.heads[alone], strict.heads[alone])
    np.testing.assert_array_equal(helped.rotations[alone], strict.rotations[alone])


def test_elbows_and_knees_come_out_as_pure_hinges_with_the_twist_on_the_upper_bone(pickup):
    """Far targets (wrists and ankles 45 frames later, pelvis kept): where the solver turned a bend plane about
    the upper arm / thigh, that bone's rotation carries the twist, so the start hinge axis turned with the
    upper bone is perpendicular to the new lower bone (the lower bone lies in the upper bone's local hinge
    plane), the twist stays within the limit, and the lower bone turns relative to the upper one about that
    axis only (a pure hinge: the elbow or knee does not twist)."""
    clip, model = pickup
    frames = np.arange(100, 1300, 60)
    h, t = clip.bones(frames)
    later, _ = clip.bones(frames + 45)
    tg = np.stack([_current(model, later, e) for e in EFFECTORS], axis=1)
    tg = tg - later[:, None, model.root] + h[:, None, model.root]
    res = adjust_frames(model, h, t, tg, EFFECTORS)
    limits = default_limits(model, h, t)
    twists = []
    for name in ("arm.L", "arm.R", "leg.L", "leg.R"):
        limb = model.limbs[name]
        i = len(limb.bones) - 1  # the hinge joint, between the last two bones
        upper, lower = limb.bones[i - 1], limb.bones[i]
        axis0 = limits[name].limits.hinge_axis[:, i]
        d0 = h[:, lower] - h[:, upper]
        axis0 = axis0 - np.sum(axis0 * d0, axis=1, keepdims=True) * d0 / np.sum(d0 * d0, axis=1, keepdims=True)
        axis0 /= np.linalg.norm(axis0, axis=1, keepdims=True)
        j = _joints(model, res.heads, res.tails, name)
        v = j[:, i + 1] - j[:, i]
        v /= np.linalg.norm(v, axis=1, keepdims=True)
        r_up, r_low = res.rotations[:, upper], res.rotations[:, lower]
        local_v = np.einsum("fba,fb->fa", r_up, v)  # the lower bone's direction in the upper bone's new frame
        np.testing.assert_allclose(np.sum(local_v * axis0, axis=1), 0.0, atol=1e-9)
        # The twist: from the axis carried by the upper bone's swing alone to the one it turned with.
        p = j[:, i] - j[:, i - 1]
        swung = np.einsum("fab,fb->fa", swing_rotation(d0, p), axis0)
        turned = np.einsum("fab,fb->fa", r_up, axis0)
        tau = np.arctan2(np.sum(np.cross(swung, turned) * p, axis=1) / np.linalg.norm(p, axis=1),
                         np.sum(swung * turned, axis=1))
        assert np.all(np.abs(tau) <= limits[name].limits.hinge_twist[i] + 1e-9)
        twists.append(tau)
        # Pure hinge, where the start pose lies on its own hinge (its lower bone perpendicular to the axis).
        v0 = t[:, lower] - h[:, lower]
        on_plane = np.abs(np.sum(v0 * axis0, axis=1)) <= 1e-12 * np.linalg.norm(v0, axis=1)
        relative = np.einsum("fba,fbc->fac", r_up, r_low)
        np.testing.assert_allclose(np.einsum("fab,fb->fa", relative, axis0)[on_plane], axis0[on_plane], atol=1e-9)
        assert on_plane.mean() > 0.5
    assert np.max(np.abs(twists)) > 0.1  # the solver did turn some bend planes


def test_limbs_already_at_their_targets_are_left_exactly_as_they_were(rig):
    """Feet targets at the ankles, a hand target within the arm's reach: the legs and feet are not re-solved
    (positions bit-identical, rotations exactly identity, not moved), obstacles elsewhere or not."""
    model, h, t = rig
    up, left, forward = (v[0] for v in model.body_frame(h, t))
    tg = _targets(model, h, t, **{"foot.L": _current(model, h, "foot.L"), "foot.R": _current(model, h, "foot.R"),
                                  "hand.L": _current(model, h, "hand.L") + 0.08 * forward + 0.05 * up})
    far = Boxes(h[0, model.root][None] + 5.0, h[0, model.root][None] + 6.0)
    for obstacles in (None, far):
        res = adjust_frames(model, h, t, tg, EFFECTORS, obstacles=obstacles)
        assert list(res.status[0]) == ["reached", "unconstrained", "reached", "reached"]
        legs = [b for g in ("leg.L", "leg.R", "foot.L", "foot.R") for b in model.groups[g]]
        still = sorted(_descendants(model, legs))
        assert np.array_equal(res.heads[:, still], h[:, still]) and np.array_equal(res.tails[:, still], t[:, still])
        assert np.array_equal(res.rotations[:, still], np.broadcast_to(np.eye(3), (1, len(still), 3, 3)))
        assert _moved_groups(model, h, t, res) == {"arm.L", "hand.L"}


def test_elbow_never_bends_backwards_on_a_target_behind_it(synth):
    model, h, t = synth
    arm = _joints(model, h, t, "arm.L")[0]
    shoulder = arm[1]
    # A target that plain FABRIK reaches by bending the elbow the wrong way: close to the shoulder, behind.
    target = shoulder + np.array([0.0, 0.12, -0.2])
    limits = default_limits(model, h, t)
    res = adjust_frames(model, h, t, _targets(model, h, t, **{"hand.L": target}), EFFECTORS)
    _assert_limits_hold(model, h, t, res, limits)


# ---------------------------------------------------------------------------------------------------------
# Many frames at once


def test_batch_equals_single_frames_within_1e9(pickup):
    clip, model = pickup
    rng = np.random.default_rng(11)
    frames = rng.choice(np.arange(1, clip.frame_count - 60), 10, replace=False)
    h, t = clip.bones(frames)
    later, _ = clip.bones(frames + 60)
    tg = np.stack([_current(model, later, e) for e in EFFECTORS], axis=1)
    tg[rng.random((10, 4)) < 0.3] = np.nan  # no target on some frames
    # A shared box in front of the pelvis of the first frame, so some chains take the obstacle path.
    front = h[0, model.root] + 0.25 * model.body_frame(h, t)[2][0]
    boxes = Boxes(front[None] - 0.1, front[None] + 0.1)
    batch = adjust_frames(model, h, t, tg, EFFECTORS, np.array([1.0, 2.0, 5.0, 5.0]), obstacles=boxes)
    for i in range(len(frames)):
        one = adjust_pose(model, h[i], t[i], tg[i], EFFECTORS, np.array([1.0, 2.0, 5.0, 5.0]), obstacles=boxes)
        np.testing.assert_allclose(one.heads, batch.heads[i], atol=1e-9, rtol=0)
        np.testing.assert_allclose(one.tails, batch.tails[i], atol=1e-9, rtol=0)
        np.testing.assert_allclose(one.rotations, batch.rotations[i], atol=1e-9, rtol=0)
        np.testing.assert_allclose(one.residuals, batch.residuals[i], atol=1e-9, rtol=0)
        assert list(one.status) == list(batch.status[i])
        assert one.iterations == batch.iterations[i]
    assert np.all(batch.status[np.isnan(tg[..., 0])] == "unconstrained")


def test_per_frame_obstacles_batch_equals_single(synth):
    model, h1, t1 = synth
    f = 4
    h, t = np.repeat(h1, f, 0), np.repeat(t1, f, 0)
    wrist = _current(model, h, "hand.L")
    offsets = np.array([[0.1, -0.25, 0.15], [0.05, -0.2, 0.1], [0.12, -0.3, 0.05], [0.0, -0.25, 0.2]])
    tg = _targets(model, h, t, **{"hand.L": wrist + offsets})
    mids = wrist + offsets * 0.5
    boxes = Boxes(mids[:, None] - 0.02, mids[:, None] + 0.02)
    batch = adjust_frames(model, h, t, tg, EFFECTORS, obstacles=boxes)
    for i in range(f):
        one = adjust_frames(model, h[i:i + 1], t[i:i + 1], tg[i:i + 1], EFFECTORS,
                            obstacles=Boxes(boxes.mins[i:i + 1], boxes.maxs[i:i + 1]))
        np.testing.assert_allclose(one.heads[0], batch.heads[i], atol=1e-9, rtol=0)


# ---------------------------------------------------------------------------------------------------------
# Head target and input errors


def test_head_target_moves_the_neck_only(rig):
    model, h, t = rig
    head_bone = model.groups["head"][-1]
    neck = h[0, model.groups["head"][0]]
    # Nod 15 deg forward about the neck base. With one neck bone the head can only move on that sphere; with
    # more, the target comes 3 % closer (a straight neck at full stretch converges slowly in FABRIK).
    up, left, forward = (v[0] for v in model.body_frame(h, t))
    c, s = np.cos(np.radians(15)), np.sin(np.radians(15))
    v = h[0, head_bone] - neck
    nod = v * c + np.cross(left, v) * s + left * np.dot(left, v) * (1 - c)  # about left: up turns to forward
    assert np.dot(nod - v, forward) > 0
    closer = 1.0 if len(model.groups["head"]) == 2 else 0.97
    target = neck + nod * closer
    tg = np.concatenate([_targets(model, h, t), target[None, None]], axis=1)
    res = adjust_frames(model, h, t, tg, EFFECTORS + ("head",))
    assert res.residuals[0, 4] <= TOL and res.sc_displacement[0] == 0.0
    assert _moved_groups(model, h, t, res) == {"head"}


@pytest.mark.parametrize("kwargs, message", [
    ({"targets": np.zeros((1, 3, 3))}, "targets must have shape"),
    ({"targets": np.array([[[0, 0, np.nan]] * 4])}, "target has NaN/inf"),
    ({"effectors": ("hand.L", "hand.L", "foot.L", "foot.R")}, "listed twice"),
    ({"effectors": ("hand.L", "hand.R", "foot.L", "tail")}, "unknown effector 'tail'"),
    ({"priorities": np.array([1.0, -1.0, 1.0, 1.0])}, "priorities must be finite numbers >= 0"),
    ({"heads": np.full((1, 27, 3), np.nan)}, "heads have NaN/inf"),
])
def test_bad_input_is_rejected(synth, kwargs, message):
    model, h, t = synth
    args = {"heads": h, "tails": t, "targets": np.zeros((1, 4, 3)), "effectors": EFFECTORS, "priorities": None}
    args["heads"] = h.copy()
    args.update(kwargs)
    if args["heads"].shape != h.shape:
        args["heads"] = np.full(h.shape, np.nan)
    with pytest.raises(SolverInputError, match=message):
        adjust_frames(model, args["heads"], args["tails"], args["targets"], args["effectors"], args["priorities"])


def test_limits_can_be_replaced_or_dropped(synth):
    model, h, t = synth
    target = _current(model, h, "hand.L") + np.array([0.0, 0.1, 0.25])  # up and behind: elbow bends backwards
    tg = _targets(model, h, t, **{"hand.L": target})
    none = adjust_frames(model, h, t, tg, EFFECTORS, limits={})
    off = adjust_frames(model, h, t, tg, EFFECTORS, settings=AdjustSettings(use_limits=False))
    np.testing.assert_array_equal(none.heads, off.heads)
    defaults = default_limits(model, h, t)
    given_ = adjust_frames(model, h, t, tg, EFFECTORS, limits=defaults)
    on = adjust_frames(model, h, t, tg, EFFECTORS)
    np.testing.assert_array_equal(given_.heads, on.heads)
    assert not np.array_equal(on.heads, off.heads)
    bad = dict(defaults)
    bad["arm.L"] = type(defaults["arm.L"])(defaults["arm.L"].limits, None)
    with pytest.raises(SolverInputError, match="joint 0 is limited but has no parent_direction"):
        adjust_frames(model, h, t, tg, EFFECTORS, limits=bad)
    with pytest.raises(SolverInputError, match="limits given for unknown limb 'tail'"):
        adjust_frames(model, h, t, tg, EFFECTORS, limits={"tail": defaults["arm.L"]})


def test_zero_length_chain_segment_is_rejected(synth):
    model, h, t = synth
    h2 = h.copy()
    hand = model.groups["hand.L"][0]
    fore = model.groups["arm.L"][-1]
    h2[0, hand] = h2[0, fore]  # wrist on the elbow
    with pytest.raises(SolverInputError, match=r"arm.L: chain segment 2 \(from bone 'forearm.L'\) has zero length"):
        adjust_frames(model, h2, t, _targets(model, h, t), EFFECTORS)
