"""Where a limb's clearance kept it from its target, the start its retries begin from (obstacles/easing.py).

A limb's last two segments (upper arm and forearm, thigh and shin) meeting a target leave one freedom: the swivel,
the middle joint (elbow, knee) anywhere on the circle around the line from the two segments' root to the target.
FABRIK moves that joint only as far as the boxes push it, so where the side that keeps the limb's surface out lies
more than a quarter turn away it stops on the near side, its centre line just out of the box and its surface in
it (kaykit_manny's chunky forearm around a box where the forearm was: 104 mesh vertices inside). The retries
start from the sampled swivel (swivel_starts) that comes least into the clearance (intrusion)."""

import numpy as np

from ..maths.geometry import cross, norm, outward_angles, rotate_about_axis, unit_or_perpendicular
from .boxes import distances_to_boxes
from ..chain.two_bone_start import two_bone_start

# Swivel angles tried, from the start's own bend outward (on a tie the smallest turn wins), and the points along
# each segment whose distances to the boxes score a chain.
ANGLES = outward_angles(12)
_ALONG = np.linspace(0.0, 1.0, 9)


def swivel_starts(start, targets):
    """(b,k,n,3): chains `start` (b,n,3) with their last two segments placed by two_bone_start so the end meets
    `targets` (b,3), the middle joint at each of the k ANGLES about the line from the two segments' root to the
    target (0: the start's own bend side); segment lengths kept, the joints before the two as two_bone_start
    leaves them. A chain of one segment has no swivel: k copies of its start."""
    b, n = start.shape[:2]
    k = len(ANGLES)
    if n < 3:
        return np.repeat(start[:, None], k, axis=1)
    m = n - 1
    upper, lower = start[:, m - 1] - start[:, m - 2], start[:, m] - start[:, m - 1]
    line = start[:, m] - start[:, m - 2]
    bend = cross(upper, lower)  # two_bone_start bends the middle joint to its axis's positive side
    bend_n, line_n = norm(bend), norm(line)
    bend = unit_or_perpendicular(bend, bend_n, bend_n > 1e-12 * np.maximum(norm(upper) * norm(lower), 1e-300), line)
    line = unit_or_perpendicular(line, line_n, line_n > 1e-300, upper)
    axes = rotate_about_axis(np.repeat(bend, k, axis=0), np.repeat(line, k, axis=0), np.tile(ANGLES, b))
    return two_bone_start(np.repeat(start, k, axis=0), np.repeat(targets, k, axis=0), axes).reshape(b, k, n, 3)


def intrusion(chains, boxes, clearance):
    """(b,k): how far chains (b,k,n,3) come into `clearance` (b,) from `boxes` (Boxes shared, or per problem for
    the b problems): the sum, over points along every segment, of how far each lies within the clearance."""
    b, k, n = chains.shape[:3]
    if len(boxes) == 0:
        return np.zeros((b, k))
    roots, ends = chains[:, :, :-1], chains[:, :, 1:]
    points = roots[:, :, :, None] + _ALONG[:, None] * (ends - roots)[:, :, :, None]  # (b,k,n-1,S,3)
    near = distances_to_boxes(points.reshape(b, -1, 3), boxes).min(axis=-1)  # (b, k*(n-1)*S)
    within = np.maximum(np.asarray(clearance, dtype=np.float64)[:, None] - near, 0.0)
    return within.reshape(b, k, -1).sum(axis=-1)
