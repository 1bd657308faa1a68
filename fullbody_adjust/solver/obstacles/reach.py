"""Which obstacles a solve can meet at all. Every bone of a solved pose lies within a ball around the root's start
head (body_reach), so a box wholly outside that ball on every frame can neither hold a joint nor be crossed by a
segment, and is left out before any test (reachable_boxes): a scene's set, hundreds of meshes away from the
character, then costs a solve nothing.

The ball's radius, per frame, with S the skeleton's reach from its root (the longest path from the root's head
along the bones: head-to-head steps, then the bone's length) and T the distance from the root's head to the farthest
target:
  - a bone that moves stays within S of the root's new place (bones are rigid, chains keep their segment lengths);
  - the root moves by a point of the sub-base balls (reach_balls.sub_base_point: within a ball, or a mean of points
    of the balls): each ball's centre is a target, or the SC's new place, less an offset within the skeleton, and its
    radius a limb's reach, so the root moves by at most T + 5S (the SC itself goes at most T + 3S from the root's
    head);
  - a bone that does not move (outside the body model) stays where it starts.
The radius used is T + 8S, or the farthest start point if that is farther: loose on purpose, since a box it keeps
only costs its tests. A limb with a clearance (AdjustSettings.clearance: its surface's radius plus the margin) tests
against its boxes grown by it: the caller adds the margin to the radius, and the surface's radius, a limb's
thickness, lies well within the 2S the bound has to spare."""

import numpy as np

from ..body.model import FIXED
from ..maths.geometry import any_set, norm

# The root's move bound (T + 5S) and a bone's reach from it (S), with room to spare: see the module notes.
_SKELETON_REACHES = 8.0


def body_reach(model, heads, tails, targets, reach=None):
    """(centre (F,3), radius (F,)): the ball no bone leaves in a solve of `model` from start poses heads, tails
    (F,J,3) toward targets (F,E,3) (NaN rows: none). `reach`: skeleton_reach of these poses, when the caller
    keeps it."""
    root = heads[:, model.root]
    far = norm(targets - root[:, None, :])
    far = np.where(np.isnan(far), 0.0, far).max(axis=1) if far.shape[1] else np.zeros(len(root))
    spread = np.maximum(norm(heads - root[:, None, :]).max(axis=1), norm(tails - root[:, None, :]).max(axis=1))
    reach = skeleton_reach(model, heads, tails) if reach is None else reach
    return root, np.maximum(spread, far + _SKELETON_REACHES * reach)


def skeleton_reach(model, heads, tails):
    """(F,) the longest path from the root's head along the moving bones: head-to-head steps from the root, then
    the bone's own length. Summed up the hierarchy by pointer jumping (a few numpy steps, not one per bone)."""
    parents = np.array(model.parents)
    parents[model.root] = -1  # paths start at the root (bones above it do not move)
    linked = parents >= 0
    up = np.where(linked, parents, 0)
    path = np.where(linked, norm(heads - heads[:, up]), 0.0)  # (F,J): the step from the parent's head
    while any_set(linked):
        path = path + np.where(linked, path[:, up], 0.0)
        linked = linked & linked[up]
        up = up[up]
    moving = model.roles != FIXED
    return (path + norm(tails - heads))[:, moving].max(axis=1)


def reachable_boxes(boxes, centre, radius):
    """`boxes` (Boxes, shared or per frame) without those whose world bounds lie farther than `radius` (F,) from
    `centre` (F,3) on every frame; the same object when none is left out, None when all are."""
    corners = boxes.corners()  # (K,8,3) or (F,K,8,3)
    lo, hi = corners.min(axis=-2), corners.max(axis=-2)
    c = centre[:, None, :]
    gap = norm(np.maximum(np.maximum(lo - c, c - hi), 0.0))  # (F,K): the centre's distance to each box
    keep = (gap <= radius[:, None]).any(axis=0)
    if keep.all():
        return boxes
    if not keep.any():
        return None
    return boxes.take(np.nonzero(keep)[0])
