"""The prepared start pose (solver/fullbody/prepared.py): the target-independent work kept per start pose changes no
result, is never stale, and its default limits hold the start chains.

Expectations come from solves that keep nothing from before (a fresh copy of the model, which holds what is kept,
or the same limits given explicitly, which makes every limb run its chain solve)."""

from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from fullbody_adjust.solver.fullbody import prepared
from fullbody_adjust.solver.fullbody.adjust import AdjustSettings, adjust_frames, adjust_pose
from fullbody_adjust.solver.limits.human import HumanLimits, default_limits
from fullbody_adjust.solver.chain.fabrik import solve_chain_batch
from fullbody_adjust.solver.limits.joint_limits import CONE
from tests.helpers import metarig

FIELDS = ("heads", "tails", "rotations", "residuals", "status", "reasons", "iterations")


@pytest.fixture(scope="module")
def rig():
    return metarig.load()


def _fresh(rig):
    """The rig with a copy of its model: the same body, nothing kept from earlier solves."""
    model, h, t, x = rig
    return replace(model), h, t, x


def _assert_same(a, b):
    for field in FIELDS:
        np.testing.assert_array_equal(getattr(a, field), getattr(b, field), err_msg=field)


def _solve(rig, targets, boxes=None, heads=None, **kwargs):
    model, h, t, x = rig
    return adjust_pose(model, h if heads is None else heads, t, targets, metarig.EFFECTORS, metarig.PRIORITIES,
                       obstacles=boxes, bone_x_axes=x, **kwargs)


# Tight cones on the trunk, shoulders and hips: the start pose itself breaks them, so a limb at its target must still
# be solved (the start may not be returned unchecked).
TIGHT = HumanLimits(spine=0.02, lumbar=0.02, clavicle=0.02, shoulder=0.05, hip=0.05)


@settings(deadline=None, max_examples=10)
@given(kind=st.sampled_from(metarig.CASES), hand_offsets=arrays(np.float64, (2, 3), elements=st.floats(-0.3, 0.3)),
       keep_left=st.booleans(), tight=st.booleans())
def test_default_limits_from_the_prepared_start_equal_the_same_limits_given(rig, kind, hand_offsets, keep_left,
                                                                          tight):
    """Given explicitly, limits bypass every shortcut of the prepared start (each limb runs its chain solve);
    the result must be bit-identical. Planted feet (and a hand left where it is) are the limbs the shortcut
    leaves untouched."""
    model, h, t, x = rig
    targets, boxes = metarig.case(model, h, t, kind)
    start = metarig.wrists_and_ankles(model, h)
    targets[:2] = start[:2] + hand_offsets
    if keep_left:
        targets[0] = start[0]
    adjust = replace(AdjustSettings(), human_limits=TIGHT) if tight else AdjustSettings()
    given_limits = default_limits(model, h[None], t[None], adjust.human_limits, x[None])
    _assert_same(_solve(rig, targets, boxes, settings=adjust),
                 _solve(rig, targets, boxes, settings=adjust, limits=given_limits))


def test_every_start_chain_holds_its_own_default_limits(rig):
    """The default limits widen to hold the start pose (start_range.py): even with cones tighter than the rig's
    rest (TIGHT), each limb's start chain aimed at its own end is returned untouched by the chain solver (0
    iterations); each cone is the HumanLimits' one or, where the start lies beyond it, the start's own angle."""
    model, h, t, x = rig
    widened = 0
    for human in (HumanLimits(), TIGHT):
        adjust = replace(AdjustSettings(), human_limits=human)
        limits = prepared.prepare(model, h[None], t[None], adjust, x[None]).limits
        given = {human.lumbar, human.spine, human.clavicle, human.shoulder, human.hip, human.neck}
        for name, limb in model.limbs.items():
            c0 = limb.joints(h[None], t[None])
            ll = limits[name]
            reference = np.diff(c0, axis=1)
            reference = np.concatenate([reference[:, :1], reference[:, :-1]], axis=1)
            res = solve_chain_batch(c0, c0[:, -1], settings=adjust.chain, parent_directions=ll.parent_direction,
                                    limits=ll.limits.derived(hinge_reference=reference))
            assert res.iterations[0] == 0, (human, name)
            segs = np.diff(c0[0], axis=0)
            for i in np.nonzero(ll.limits.kind == CONE)[0]:
                parent = ll.parent_direction[0] if i == 0 else segs[i - 1]
                cos = parent @ segs[i] / np.linalg.norm(parent) / np.linalg.norm(segs[i])
                angle = np.arccos(np.clip(cos, -1.0, 1.0))
                cone = ll.limits.cone_angle[i]
                if cone not in given:
                    assert cone == pytest.approx(angle, abs=1e-7) and cone > min(given), (name, i)
                    widened += 1
    assert widened > 0  # TIGHT's cones did not hold the rest: widened


def test_a_start_pose_changed_in_place_is_a_new_start(rig):
    model, h, t, x = rig
    targets, _ = metarig.case(model, h, t, "near")
    heads = h.copy()
    first = _solve(rig, targets, heads=heads)
    heads[model.limbs["arm.L"].bones[-1]] += np.array([0.0, -0.02, 0.0])  # the left elbow moved in place
    moved = _solve(rig, targets, heads=heads)
    _assert_same(moved, _solve(_fresh(rig), targets, heads=heads.copy()))
    assert not np.array_equal(moved.heads, first.heads)
    heads[:] = h  # back to the first start: the same answer as the first time
    _assert_same(first, _solve(rig, targets, heads=heads))


def test_frames_sharing_a_start_pose_equal_their_solves_alone(rig):
    """A frame range whose start poses are prepared once; each frame equals a solve of that frame alone by a
    model that kept nothing."""
    model, h, t, x = rig
    base, boxes = metarig.case(model, h, t, "near")
    rng = np.random.default_rng(5)
    n = 4
    targets = np.repeat(base[None], n, 0)
    targets[1:, :2] += rng.normal(scale=0.1, size=(n - 1, 2, 3))  # frame 0: the hands' targets as they are
    heads = np.repeat(h[None], n, 0)
    heads[2] += 0.01  # one frame's whole pose shifted: a different start
    tails = np.repeat(t[None], n, 0)
    tails[2] += 0.01
    batch = adjust_frames(model, heads, tails, targets, metarig.EFFECTORS, metarig.PRIORITIES,
                          bone_x_axes=np.repeat(x[None], n, 0))
    for f in range(n):
        one = adjust_pose(replace(model), heads[f], tails[f], targets[f], metarig.EFFECTORS, metarig.PRIORITIES,
                          bone_x_axes=x)
        np.testing.assert_allclose(one.heads, batch.heads[f], atol=1e-9, rtol=0)
        np.testing.assert_allclose(one.rotations, batch.rotations[f], atol=1e-9, rtol=0)
        assert list(one.status) == list(batch.status[f])


def _limit_arrays(ll):
    lim = ll.limits
    return (lim.kind, lim.cone_angle, lim.hinge_axis, lim.hinge_min, lim.hinge_max, lim.hinge_twist,
            ll.parent_direction)


def test_limbs_kept_from_a_recent_start_give_each_start_its_own_limits(rig, monkeypatch):
    """Each start's default limits equal those computed afresh, while limbs whose inputs did
    not change are taken from the start before: a straight left arm (its hinge from its forearm's X axis), then
    only that X axis turned; without X axes (its hinge from the body's forward), then only the right hip moved
    (which turns the forward); only the root bone turned (the pelvis' up); and the first start again."""
    model, h, t, x = rig
    arm = model.limbs["arm.L"]
    upper, fore = arm.bones[-2], arm.bones[-1]
    heads, tails = h.copy(), t.copy()
    direction = (tails[upper] - heads[upper]) / np.linalg.norm(tails[upper] - heads[upper])
    wrist = heads[fore] + direction * np.linalg.norm(tails[fore] - heads[fore])
    hand_vector = tails[arm.end_bone] - heads[arm.end_bone]
    tails[fore], heads[arm.end_bone], tails[arm.end_bone] = wrist, wrist, wrist + hand_vector
    turned_x = x.copy()
    turned_x[fore] = np.cross(direction, x[fore])
    hip_moved = heads.copy()
    hip_moved[model.limbs["leg.R"].bones[0]] += np.array([0.0, 0.05, 0.0])
    root_turned = tails.copy()
    root_turned[model.root] += np.array([0.05, 0.0, 0.0])
    starts = [(heads, tails, x), (heads, tails, turned_x), (heads, tails, None), (hip_moved, tails, None),
              (heads, root_turned, x), (heads, tails, x)]
    computed = []
    limb_limits = prepared.LimitStart.limb_limits
    monkeypatch.setattr(prepared.LimitStart, "limb_limits",
                        lambda self, limb, human: computed.append(limb.name) or limb_limits(self, limb, human))
    adjust = AdjustSettings()

    def prepared_limits(solving, hh, tt, xx):
        computed.clear()
        prep = prepared.prepare(solving, hh[None], tt[None], adjust, None if xx is None else xx[None])
        out = {name: _limit_arrays(ll) for name, ll in prep.limits.items()}
        out["computed"] = set(computed)
        return out

    clicking = replace(model)  # nothing kept from the other tests
    kept = [prepared_limits(clicking, *start) for start in starts]  # one after the other, as clicks come
    fresh = [prepared_limits(replace(model), *start) for start in starts]
    for k, (a, b) in enumerate(zip(kept, fresh)):
        for name in model.limbs:
            for u, v in zip(a[name], b[name]):
                np.testing.assert_array_equal(u, v, err_msg=f"start {k}, {name}")
    # Each change reached what it should, so the starts test the inputs a kept limb is matched on ...
    assert not np.array_equal(fresh[1]["arm.L"][2], fresh[0]["arm.L"][2])  # the X axis turned the hinge
    assert not np.array_equal(fresh[3]["arm.L"][2], fresh[2]["arm.L"][2])  # the hip turned the hinge
    assert not np.array_equal(fresh[4]["leg.L"][6], fresh[0]["leg.L"][6])  # the root turned the pelvis' up
    # ... and the limbs whose inputs stayed were kept, not computed again.
    assert kept[0]["computed"] == set(model.limbs) and kept[1]["computed"] == {"arm.L"}
    assert kept[5]["computed"] == set()
