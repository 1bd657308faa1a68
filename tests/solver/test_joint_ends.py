"""solver.joint_ends: where a bone ends as a joint, whatever its tail says."""

import numpy as np

from fullbody_adjust.solver.body.joint_ends import chain_successors, end_points, joint_ends


def _rest(heads, rotations=None):
    rest = np.tile(np.eye(4), (len(heads), 1, 1))
    rest[:, :3, 3] = heads
    if rotations is not None:
        rest[:, :3, :3] = rotations
    return rest


def _turn(axis, angle):
    axis = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


# pelvis(0) -> spine(1) -> chest(2) -> neck(3) -> head(4); chest -> upper arm(5) -> forearm(6) -> hand(7)
# -> finger(8); pelvis -> thigh(9) -> shin(10) -> foot(11) -> toe(12); chest also parents a helper(13) at its head.
PARENTS = np.array([-1, 0, 1, 2, 3, 2, 5, 6, 7, 0, 9, 10, 11, 2])
HEADS = np.array([[0, 0, 1.0], [0, 0, 1.1], [0, 0, 1.3], [0, 0, 1.5], [0, 0, 1.6], [0.2, 0, 1.45], [0.5, 0, 1.45],
                  [0.75, 0, 1.45], [0.85, 0, 1.45], [0.1, 0, 0.95], [0.1, 0, 0.5], [0.1, 0, 0.08], [0.1, -0.12, 0.02],
                  [0, 0, 1.3]])
GROUPS = {"root": (0,), "trunk": (1, 2), "head": (3, 4), "arm.L": (5, 6), "hand.L": (7,), "leg.L": (9, 10),
          "foot.L": (11,)}


def _far_tails(scale):
    """Tails as Blender's glTF importer may leave them: along a random direction, far past any joint."""
    rng = np.random.default_rng(3)
    directions = rng.normal(size=HEADS.shape)
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    return HEADS + scale * directions


def test_chain_bones_end_at_their_successor_whatever_the_tails():
    rotations = np.stack([_turn(np.random.default_rng(k).normal(size=3), 0.3 * k) for k in range(len(HEADS))])
    rest = _rest(HEADS, rotations)
    ends = end_points(rest, joint_ends(PARENTS, rest, _far_tails(40.0), GROUPS))
    # Chain successors: spine -> chest -> neck (the SC), neck -> head, upper arm -> forearm -> hand, thigh -> shin
    # -> foot; a single child: pelvis has three, foot -> toe (its only child).
    for bone, nxt in ((1, 2), (2, 3), (3, 4), (5, 6), (6, 7), (9, 10), (10, 11), (11, 12), (7, 8)):
        np.testing.assert_allclose(ends[bone], HEADS[nxt], atol=1e-12)


def test_leaves_and_forks_keep_their_tails_direction_at_a_joint_length():
    tails = _far_tails(40.0)
    rest = _rest(HEADS)
    ends = end_points(rest, joint_ends(PARENTS, rest, tails, GROUPS))
    for bone in (4, 8, 12):  # leaves: the parent's joint length, along the tail
        parent = PARENTS[bone]
        parent_end = ends[parent]
        length = np.linalg.norm(parent_end - HEADS[parent])
        np.testing.assert_allclose(np.linalg.norm(ends[bone] - HEADS[bone]), length, rtol=1e-12)
        direction = (tails[bone] - HEADS[bone]) / np.linalg.norm(tails[bone] - HEADS[bone])
        np.testing.assert_allclose((ends[bone] - HEADS[bone]) / length, direction, atol=1e-12)
    # The pelvis forks into spine and thighs: no longer than its farthest child's head.
    farthest = max(np.linalg.norm(HEADS[c] - HEADS[0]) for c in (1, 9))
    np.testing.assert_allclose(np.linalg.norm(ends[0] - HEADS[0]), farthest, rtol=1e-12)


def test_plausible_tails_are_kept_and_ends_ride_on_the_pose():
    tails = HEADS + np.array([0, 0, 0.05])  # short tails, all shorter than any cap
    tails[[1, 2, 3, 5, 6, 9, 10, 11, 7]] = HEADS[[2, 3, 4, 6, 7, 10, 11, 12, 8]]
    rest = _rest(HEADS)
    local = joint_ends(PARENTS, rest, tails, GROUPS)
    np.testing.assert_allclose(end_points(rest, local), tails, atol=1e-12)
    # Posed: an end rides on its bone (rotation and translation of its matrix), frames batched.
    turn = _turn([1, 2, 3], 0.7)
    pose = np.array([rest, rest])
    pose[1, :, :3, :3] = turn @ rest[:, :3, :3]
    pose[1, :, :3, 3] += [0.3, -0.2, 0.1]
    ends = end_points(pose, local)
    np.testing.assert_allclose(ends[0], tails, atol=1e-12)
    np.testing.assert_allclose(ends[1] - pose[1, :, :3, 3], (tails - HEADS) @ turn.T, atol=1e-12)


def test_neck_follows_the_trunk_only_when_it_hangs_from_it():
    parents = PARENTS.copy()
    parents[3] = 0  # the neck hangs from the pelvis (a rig without a spine between)
    successors = chain_successors(GROUPS, parents)
    assert successors[2] == -1 and successors[1] == 2 and successors[6] == 7 and successors[10] == 11
    assert chain_successors(GROUPS, PARENTS)[2] == 3
