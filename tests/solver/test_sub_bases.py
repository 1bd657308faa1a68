"""Where the pelvis goes when the SC must move farther than the trunk reaches (solver/fullbody/sub_bases.py): on a body
with a short trunk and short arms reaching out to the sides (as a plush toy's), a hand held where it stands
leans the SC toward it, and the pelvis, translating for the far hand, does not slide along the hips' line for
that; a target out to the side asks for the side, and the pelvis follows it there."""

import numpy as np
import pytest

from fullbody_adjust.solver.fullbody.adjust import AdjustSettings, adjust_pose
from fullbody_adjust.solver.body.model import BodyModel

TOL = AdjustSettings().chain.tolerance
EFFECTORS = ("hand.L", "hand.R", "foot.L", "foot.R")
LEFT = np.array([1.0, 0.0, 0.0])  # Z up, facing -Y: the left hip lies toward +X
FORWARD = np.array([0.0, -1.0, 0.0])
UP = np.array([0.0, 0.0, 1.0])


def plush():
    """A stout body: a short two-bone trunk from the pelvis to the SC, wide shoulders with arms reaching out and
    down to the hands, slightly bent knees."""
    bones = []

    def add(name, parent, head, tail):
        bones.append((name, parent, np.array(head, float), np.array(tail, float)))

    add("pelvis", None, (0, 0, 0.8), (0, 0, 0.9))
    add("spine", "pelvis", (0, 0, 0.8), (0, 0.01, 1.05))
    add("chest", "spine", (0, 0.01, 1.05), (0, 0, 1.32))
    for s, x in (("L", 1.0), ("R", -1.0)):
        add(f"upper_arm.{s}", "chest", (0.52 * x, 0, 0.82), (0.58 * x, -0.01, 0.73))
        add(f"forearm.{s}", f"upper_arm.{s}", (0.58 * x, -0.01, 0.73), (0.64 * x, 0, 0.65))
        add(f"hand.{s}", f"forearm.{s}", (0.64 * x, 0, 0.65), (0.68 * x, 0, 0.6))
        add(f"thigh.{s}", "pelvis", (0.15 * x, 0, 0.75), (0.15 * x, -0.08, 0.4))
        add(f"shin.{s}", f"thigh.{s}", (0.15 * x, -0.08, 0.4), (0.15 * x, 0, 0.06))
        add(f"foot.{s}", f"shin.{s}", (0.15 * x, 0, 0.06), (0.15 * x, -0.1, 0.0))
    names = [b[0] for b in bones]
    parents = [-1 if b[1] is None else names.index(b[1]) for b in bones]
    groups = {"root": ["pelvis"], "trunk": ["spine", "chest"]}
    for s in "LR":
        groups.update({f"arm.{s}": [f"upper_arm.{s}", f"forearm.{s}"], f"hand.{s}": [f"hand.{s}"],
                       f"leg.{s}": [f"thigh.{s}", f"shin.{s}"], f"foot.{s}": [f"foot.{s}"]})
    model = BodyModel.from_description(names, parents, groups)
    return model, names, np.array([b[2] for b in bones]), np.array([b[3] for b in bones])


def tails_sc(body):
    model, names, heads, tails = body
    return tails[names.index("chest")]


@pytest.fixture(scope="module")
def body():
    return plush()


def _solve(body, direction):
    """Both hands and feet held where they stand but the right hand, whose target is 1.8 arm lengths from its
    shoulder along `direction`. Returns (result, start heads, bone index by name, right hand's target)."""
    model, names, heads, tails = body
    at = {n: i for i, n in enumerate(names)}
    shoulder = heads[at["upper_arm.R"]]
    reach = np.linalg.norm(heads[at["forearm.R"]] - shoulder) + np.linalg.norm(heads[at["hand.R"]] -
                                                                               heads[at["forearm.R"]])
    far = shoulder + 1.8 * reach * direction / np.linalg.norm(direction)
    targets = np.array([heads[at["hand.L"]], far, heads[at["foot.L"]], heads[at["foot.R"]]])
    return adjust_pose(model, heads, tails, targets, EFFECTORS), heads, at, far


def test_a_far_target_ahead_moves_the_pelvis_ahead_not_along_the_hips(body):
    res, heads, at, far = _solve(body, FORWARD + 0.1 * UP)
    # The held hand and the feet stay met; the far hand comes nearer its target than it was.
    assert np.all(res.residuals[[0, 2, 3]] <= TOL), res.reasons
    assert np.linalg.norm(res.heads[at["hand.R"]] - far) < np.linalg.norm(heads[at["hand.R"]] - far) - 0.2
    # The SC had to come farther than the trunk reaches from its base: the pelvis moved, ahead...
    moved = res.heads[at["pelvis"]] - heads[at["pelvis"]]
    assert res.root_displacement > 0.02 and moved @ FORWARD > 0.02
    # ...and the left arm's reach ball leaned the SC toward the left hand, which the trunk took on, not the
    # pelvis (on the nearest translation the pelvis slid 1.9 cm left, carrying the knees 9 mm).
    assert (res.tails[at["chest"]] - tails_sc(body)) @ LEFT > 0.02
    assert abs(moved @ LEFT) <= 1e-9, moved
    for knee in ("shin.L", "shin.R"):
        assert abs((res.heads[at[knee]] - heads[at[knee]]) @ LEFT) <= 1e-3


def test_a_far_target_to_the_side_moves_the_pelvis_to_that_side(body):
    res, heads, at, far = _solve(body, -LEFT)
    assert np.all(res.residuals[[0, 2, 3]] <= TOL), res.reasons
    assert np.linalg.norm(res.heads[at["hand.R"]] - far) < np.linalg.norm(heads[at["hand.R"]] - far) - 0.05
    moved = res.heads[at["pelvis"]] - heads[at["pelvis"]]
    assert moved @ -LEFT > 0.05, moved
