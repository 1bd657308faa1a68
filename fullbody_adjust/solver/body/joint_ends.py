"""Where each bone ends as a joint: the point a bone's length and direction are measured to, taken from the
joints of the skeleton, never from where an importer left the bone's tail.

Blender's glTF importer may leave a tail about a hundred times past the next joint, its FBX importer points every
tail along the bone's Y axis whatever the child's position, and leaf bones get a length made up by the importer.
A skeleton's joints are its bone heads; so a bone ends at

1. the head of its chain successor under the bone map: the next bone of its group, the hand (or foot) after an
   arm's (or leg's) last bone, the first neck bone after the trunk's last bone (the SC, the neck's base);
2. else the head of its only child whose head is apart from its own;
3. else (a leaf, or a bone with several children) its tail, shortened where it is implausibly long: a leaf to
   the length of its parent's joint segment, a bone with children to its farthest child's head distance.

The end is kept in the bone's own rest frame (``ends``, (J,3)), so it rides on the bone in any pose:
``end_points(pose, ends)`` are the posed ends of pose matrices (the same space as the rest matrices).
"""

from __future__ import annotations

import numpy as np

# The chain successor of a group's last bone: the first bone of this group.
_NEXT_GROUP = {"arm.L": "hand.L", "arm.R": "hand.R", "leg.L": "foot.L", "leg.R": "foot.R", "trunk": "head"}

# A child whose head is closer to its parent's head than this fraction of the skeleton's size starts where its
# parent starts (a twist or helper bone, an importer's zero-length offset): it says nothing about the end.
_APART = 1e-6


def chain_successors(groups, parents):
    """(J,) int: each bone's chain successor under ``groups`` ({group: bone indices, parent first}), -1 if none.
    The neck follows the trunk only where it hangs from the trunk's last bone (not, say, from the pelvis)."""
    successor = np.full(len(parents), -1, dtype=np.int64)
    for group, bones in groups.items():
        bones = list(bones)
        for a, b in zip(bones[:-1], bones[1:]):
            successor[a] = b
        after = list(groups.get(_NEXT_GROUP.get(group, ""), ()))
        if bones and after and (group != "trunk" or parents[after[0]] == bones[-1]):
            successor[bones[-1]] = after[0]
    return successor


def joint_ends(parents, rest, tails, groups=None):
    """Each bone's end (see the module docstring) in its own rest frame, (J,3).

    parents (J,) int (-1: none), parents before children; rest (J,4,4) the bones' rest matrices (head at the
    translation, any rotation) and tails (J,3) their rest tails, both in one space (armature space); groups: the
    bone map's {group: bone indices} or None."""
    parents = np.asarray(parents, dtype=np.int64).reshape(-1)
    rest = np.asarray(rest, dtype=np.float64)
    tails = np.asarray(tails, dtype=np.float64).reshape(-1, 3)
    count = len(parents)
    heads = rest[:, :3, 3]
    extent = np.ptp(np.concatenate([heads, tails]), axis=0) if count else np.zeros(3)
    apart = _APART * max(float(np.max(extent)) if count else 0.0, 1e-12)
    successor = chain_successors(groups or {}, parents)
    children = [[] for _ in range(count)]
    for child, parent in enumerate(parents.tolist()):
        if parent >= 0 and np.linalg.norm(heads[child] - heads[parent]) > apart:
            children[parent].append(child)

    ends = tails.copy()
    length = np.linalg.norm(tails - heads, axis=1)
    for bone in range(count):  # parents first: a leaf's cap is its parent's final length
        nxt = int(successor[bone])
        if nxt >= 0 and np.linalg.norm(heads[nxt] - heads[bone]) > apart:
            ends[bone] = heads[nxt]
        elif len(children[bone]) == 1:
            ends[bone] = heads[children[bone][0]]
        else:
            if children[bone]:
                cap = max(float(np.linalg.norm(heads[c] - heads[bone])) for c in children[bone])
            else:
                parent = int(parents[bone])
                cap = float(length[parent]) if parent >= 0 else float(length[bone])
            if length[bone] > cap > apart:
                ends[bone] = heads[bone] + (tails[bone] - heads[bone]) * (cap / length[bone])
        length[bone] = float(np.linalg.norm(ends[bone] - heads[bone]))
        if length[bone] <= apart:  # nothing better than the tail (a zero-length end would have no direction)
            ends[bone] = tails[bone]
            length[bone] = float(np.linalg.norm(tails[bone] - heads[bone]))
    # Into each bone's rest frame: R^-1 (end - head) for a rest rotation R (with any scale).
    local = np.linalg.solve(rest[:, :3, :3], (ends - heads)[..., None])[..., 0] if count else np.zeros((0, 3))
    return local


def end_points(pose, ends):
    """Posed ends (..., J, 3) of pose matrices (..., J, 4, 4) and ``joint_ends`` (J,3), in the pose's space."""
    pose = np.asarray(pose, dtype=np.float64)
    return np.einsum("...ij,...j->...i", pose[..., :3, :3], ends) + pose[..., :3, 3]
