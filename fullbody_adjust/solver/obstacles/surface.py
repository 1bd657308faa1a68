"""A limb's surface as points riding on its chain's segments (AdjustSettings.surface; bridge/reading/limb_thickness.py
reads them from the meshes the armature deforms), and how deep a pose puts them in the obstacle boxes.

A capsule round the centre line (AdjustSettings.clearance) cannot tell a fist that sticks out past the forearm's
joint end, or a chunky forearm's flat side, from a round limb: near a target that lies nearer a box than the
limb's radius every capsule enters the box, whichever way the limb turns, while the real surface may clear it
on one side. The points follow the chain as the bones do: each rides on its segment, turned by the smallest
swing from the segment's start direction to its new one, a hinge's twist carried on its parent (the rotations
the product writes: limb_rotations), so a pose's surface is known from its joints alone."""

from dataclasses import dataclass

import numpy as np

from ..errors import SolverInputError
from ..maths.geometry import all_set
from .boxes import depths_in_boxes


@dataclass(frozen=True, eq=False)
class LimbSurface:
    """P surface points of one limb: ``segment`` (P,) the chain segment each rides on (segment k: joint k to
    joint k+1), ``points`` (F,P,3) where each lies at the start pose of each of the F frames (solve space);
    ``weights`` (P,S+2) or None: each point's skinning weights over the chain's S segments, its end (the hand or
    foot, riding on the end joint: moved with it, not turned) and the rest of the body (moved with the base),
    rows adding up to 1 (None: each rides on its segment alone)."""

    segment: np.ndarray
    points: np.ndarray
    weights: np.ndarray = None

    def __post_init__(self):
        segment = np.asarray(self.segment)
        points = np.asarray(self.points, dtype=np.float64)
        if segment.ndim != 1 or points.ndim != 3 or points.shape[1:] != (segment.size, 3):
            raise SolverInputError(f"a limb surface needs segment (P,) and points (F,P,3), got {segment.shape} "
                                   f"and {points.shape}")
        if segment.size and (not np.issubdtype(segment.dtype, np.integer) or segment.min() < 0):
            raise SolverInputError("a limb surface's segments must be chain segment indices >= 0")
        if not all_set(np.isfinite(points)):
            raise SolverInputError("a limb surface's points have NaN/inf")
        if self.weights is not None:
            weights = np.asarray(self.weights, dtype=np.float64)
            if weights.ndim != 2 or weights.shape[0] != segment.size or weights.shape[1] < 3 \
                    or not all_set(np.isfinite(weights)) or (segment.size and segment.max() >= weights.shape[1] - 2):
                raise SolverInputError(f"a limb surface's weights must be (P, segments + 2) finite, got "
                                       f"{weights.shape}")
            object.__setattr__(self, "weights", weights)
        object.__setattr__(self, "segment", segment.astype(np.int64))
        object.__setattr__(self, "points", points)


def posed_points(surface, rows, start, chains, rotations):
    """(b,k,P,3): the surface points of frames ``rows`` (b,) on chains (b,k,n,3) whose segments turned by
    ``rotations`` (b,k,n-1,3,3) (world rotation deltas, limb_rotations.chain_rotations) from the frames' start
    pose chains ``start`` (b,n,3): each point turns with its segment about the segment's root, or, given weights,
    goes where its weights blend the segments', the end's and the base's moves (linear blend skinning)."""
    points = surface.points[rows]  # (b,P,3)
    if surface.weights is None:
        out = np.empty(chains.shape[:2] + points.shape[1:])
        for s in np.unique(surface.segment):
            on = surface.segment == s
            out[:, :, on] = chains[:, :, s, None] + np.einsum("bkij,bpj->bkpi", rotations[:, :, s],
                                                              points[:, on] - start[:, None, s])
        return out
    w = surface.weights
    segments = w.shape[1] - 2
    moved = chains - start[:, None]  # (b,k,n,3): each joint's move
    out = (w[:, segments, None] * moved[:, :, -1, None]  # the end rides on the end joint
           + w[:, segments + 1, None] * moved[:, :, 0, None]) + points[:, None]  # the rest on the base
    for s in range(segments):
        on = w[:, s] > 0.0
        if on.any():
            turned = chains[:, :, s, None] + np.einsum("bkij,bpj->bkpi", rotations[:, :, s],
                                                       points[:, on] - start[:, None, s])
            out[:, :, on] += w[on, s, None] * (turned - points[:, None, on])
    return out


def depth_in_boxes(points, boxes):
    """(b,k): how deep the points (b,k,P,3) lie in `boxes` (shared, or per problem for the b), added up over the
    points (each its depth in the box it lies deepest in; 0 outside every box)."""
    b, k, p = points.shape[:3]
    if len(boxes) == 0 or p == 0:
        return np.zeros((b, k))
    return depths_in_boxes(points.reshape(b, k * p, 3), boxes).max(axis=-1).reshape(b, k, p).sum(axis=-1)
