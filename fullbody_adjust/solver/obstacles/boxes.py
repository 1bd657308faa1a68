"""Obstacle boxes and the collision tests the solver and the quality measures use (paper §4.1.1).

A box is axis-aligned, or oriented: then ``axes`` holds its unit axes as columns and ``mins``/``maxs`` are its
extents along them (coordinates ``axes.T @ p``), so every test is the axis-aligned one in the box's own frame.
A rotated mesh's bounding box is then the box the user sees, not the larger axis-aligned box around it."""

from dataclasses import dataclass

import math

import numpy as np

from ..errors import SolverInputError
from ..maths import lanes
from ..maths.geometry import all_set, any_set


# Boxes whose axes are the coordinate axes to within this (each axis's other components) are taken axis-aligned:
# their corners' bounding box is then larger than the box by at most this fraction of its size, and the tests are
# the fast ones. A mesh's box through a glTF armature's quarter turn (float32 matrices) is off by about 1e-7.
_ALIGNED = 1e-6


@dataclass(frozen=True)
class Boxes:
    """K closed boxes: mins, maxs (K,3) shared by every problem of a batch, or (B,K,3) per problem (moving
    obstacles: one box set per frame). ``axes`` None: axis-aligned; else (K,3,3) or (B,K,3,3) orthonormal
    columns, the box's axes, and mins/maxs are extents along them."""

    mins: np.ndarray
    maxs: np.ndarray
    axes: np.ndarray = None

    def __post_init__(self):
        mins = np.array(self.mins, dtype=np.float64)
        maxs = np.array(self.maxs, dtype=np.float64)
        if mins.shape != maxs.shape or mins.ndim not in (2, 3) or mins.shape[-1] != 3:
            raise SolverInputError(
                f"boxes need mins and maxs of the same shape (K,3) or (B,K,3), got {mins.shape} and {maxs.shape}")
        if not (all_set(np.isfinite(mins)) and all_set(np.isfinite(maxs))):
            raise SolverInputError("obstacle boxes have NaN/inf")
        bad = np.nonzero(np.any(mins > maxs, axis=-1))
        if bad[0].size:
            raise SolverInputError(f"obstacle box {int(bad[-1][0])} has min > max")
        mins.setflags(write=False)
        maxs.setflags(write=False)
        object.__setattr__(self, "mins", mins)
        object.__setattr__(self, "maxs", maxs)
        if self.axes is not None:
            axes = np.array(self.axes, dtype=np.float64)
            if axes.shape != mins.shape + (3,):
                raise SolverInputError(f"box axes must have shape {mins.shape + (3,)}, got {axes.shape}")
            gram = np.einsum("...ji,...jk->...ik", axes, axes)
            if not (all_set(np.isfinite(axes)) and np.allclose(gram, np.eye(3), atol=1e-9)):
                raise SolverInputError("box axes must be orthonormal")
            axes.setflags(write=False)
            object.__setattr__(self, "axes", axes)

    @classmethod
    def from_corners(cls, corners):
        """Boxes bounding corner points: (K,8,3) or (K,2,3), or per problem (B,K,8,3) / (B,K,2,3)."""
        corners = np.asarray(corners, dtype=np.float64)
        if corners.ndim not in (3, 4) or corners.shape[-1] != 3 or corners.shape[-2] < 1:
            raise SolverInputError(f"box corners must have shape (K,8,3), (K,2,3) or (B,K,...,3), got {corners.shape}")
        if not all_set(np.isfinite(corners)):
            raise SolverInputError("obstacle box corners have NaN/inf")
        return cls(corners.min(axis=-2), corners.max(axis=-2))

    @classmethod
    def from_box_corners(cls, corners):
        """The boxes whose 8 corners (K,8,3) or (B,K,8,3) are given in Blender's ``bound_box`` order (corner i
        has +x where i & 4, +y where i in 2,3,6,7, +z where i in 1,2,5,6), e.g. a mesh's bounding box through
        its object transform: oriented boxes with the edges' directions as axes (a sheared box is enclosed
        in the oriented box of its nearest orthonormal axes). Boxes whose axes are the coordinate axes
        (up to order and sign, to within _ALIGNED) everywhere give axis-aligned Boxes, the faster tests."""
        corners = np.asarray(corners, dtype=np.float64)
        if corners.ndim not in (3, 4) or corners.shape[-2:] != (8, 3):
            raise SolverInputError(f"box corners must have shape (K,8,3) or (B,K,8,3), got {corners.shape}")
        if not all_set(np.isfinite(corners)):
            raise SolverInputError("obstacle box corners have NaN/inf")
        if corners.shape[-3] == 0:
            return cls(np.zeros(corners.shape[:-2] + (3,)), np.zeros(corners.shape[:-2] + (3,)))
        edges = np.stack([corners[..., 4, :] - corners[..., 0, :], corners[..., 3, :] - corners[..., 0, :],
                          corners[..., 1, :] - corners[..., 0, :]], axis=-1)  # (...,3,3): the x, y, z edges
        # The orthonormal matrix nearest the edges (polar factor): the box's own axes when they are orthogonal,
        # a valid frame when an edge has zero length (a flat mesh).
        u, _s, vt = np.linalg.svd(edges)
        axes = u @ vt
        if np.allclose(np.sort(np.abs(axes), axis=-1)[..., :2], 0.0, atol=_ALIGNED):
            return cls.from_corners(corners)
        local = np.einsum("...ji,...cj->...ci", axes, corners)
        return cls(local.min(axis=-2), local.max(axis=-2), axes)

    @classmethod
    def empty(cls):
        return cls(np.zeros((0, 3)), np.zeros((0, 3)))

    def __len__(self):
        return self.mins.shape[-2]

    @property
    def batched(self):
        return self.mins.ndim == 3

    @property
    def oriented(self):
        return self.axes is not None

    def corners(self):
        """The 8 corners of every box in world space: (K,8,3) or (B,K,8,3)."""
        bits = np.array([[(c >> 0) & 1, (c >> 1) & 1, (c >> 2) & 1] for c in range(8)], dtype=bool)
        local = np.where(bits, self.maxs[..., None, :], self.mins[..., None, :])
        if self.axes is None:
            return local
        return np.einsum("...ij,...cj->...ci", self.axes, local)

    def take(self, indices):
        """The boxes `indices` (an index array over K), shared or per problem as these are."""
        out = object.__new__(Boxes)
        for name, arr, axis in (("mins", self.mins, -2), ("maxs", self.maxs, -2), ("axes", self.axes, -3)):
            if arr is not None:
                arr = np.take(arr, indices, axis=axis)
                arr.setflags(write=False)
            object.__setattr__(out, name, arr)
        return out

    def select(self, rows):
        """Per-problem boxes of the problems `rows` (index array); shared boxes are returned unchanged. Rows of
        boxes checked once are not checked again: the chain solver selects a few times per iteration, and
        __post_init__'s checks cost more than its tests on one frame's boxes."""
        if not self.batched:
            return self
        out = object.__new__(Boxes)
        for name, arr in (("mins", self.mins[rows]), ("maxs", self.maxs[rows]),
                          ("axes", None if self.axes is None else self.axes[rows])):
            if arr is not None:
                arr.setflags(write=False)
            object.__setattr__(out, name, arr)
        return out

    def grown(self, by):
        """These boxes grown by `by`, (B,K) per problem and box (shared boxes become per-problem ones): every face
        pushed out by it along the box's own axes, so a point outside a grown box is at least `by` from the box."""
        by = np.asarray(by, dtype=np.float64)[..., None]
        mins, maxs = self.mins - by, self.maxs + by
        axes = None if self.axes is None else np.broadcast_to(self.axes, mins.shape + (3,))
        return Boxes(mins, maxs, axes)


# A box is grown by less than a limb's clearance where the limb's target or base lies nearer to it: by this
# fraction of that distance, so the point stays outside the grown box with room for the end joint's approach.
_APPROACH = 0.9


def grown_clear_of(boxes, clearance, keep_out):
    """The boxes a limb with a clearance (a limb's surface radius plus margin) tests its centre line against:
    `boxes` (shared, or per problem for B problems) grown by `clearance` (B,), each box by less where one of the
    problem's `keep_out` points (B,P,3: the chain's base and target) lies nearer to it than that, to _APPROACH of
    that distance. Such a point then stays outside the grown box: the chain's last segment still avoids the
    box, only as near as the target asks (a box holding the target or base itself is not grown, and the chain
    ignores it for that segment as the paper does). Per-problem Boxes (B,K,3)."""
    gaps = distances_to_boxes(keep_out, boxes)  # (B,P,K): per-problem boxes pair with the first axis
    return boxes.grown(np.minimum(np.asarray(clearance, dtype=np.float64)[:, None], _APPROACH * gaps.min(axis=1)))


def distances_to_boxes(points, boxes):
    """(...,3) points, K boxes -> (..., K): each point's distance to each closed box (0 inside it)."""
    p = np.asarray(points, dtype=np.float64)
    mins, maxs, axes = _box_arrays(boxes, p.ndim - 1)
    q = _in_box_frames(p, axes)
    return np.linalg.norm(np.maximum(np.maximum(mins - q, q - maxs), 0.0), axis=-1)


def depths_in_boxes(points, boxes):
    """(...,3) points, K boxes -> (..., K): how deep each point lies in each closed box (its distance to the
    box's nearest face from inside; 0 outside or on a face)."""
    p = np.asarray(points, dtype=np.float64)
    mins, maxs, axes = _box_arrays(boxes, p.ndim - 1)
    q = _in_box_frames(p, axes)
    return np.maximum(np.minimum(q - mins, maxs - q).min(axis=-1), 0.0)


def as_boxes(obstacles):
    """None, Boxes, or an array of box corners ((K,8,3), (K,2,3) or per problem (B,K,...,3)) -> Boxes or None."""
    if obstacles is None or isinstance(obstacles, Boxes):
        return obstacles
    try:
        return Boxes.from_corners(obstacles)
    except (TypeError, ValueError) as ex:
        if isinstance(ex, SolverInputError):
            raise
        raise SolverInputError(f"obstacles must be Boxes or an array of box corners: {ex}") from None


def _box_arrays(boxes, lead_ndim):
    """mins, maxs (and axes, or None) shaped to broadcast against points with `lead_ndim` leading axes, giving
    (..., K, 3) (axes (..., K, 3, 3)). Per-problem boxes pair their B axis with the points' first axis."""
    mins, maxs, axes = boxes.mins, boxes.maxs, boxes.axes
    if boxes.batched:
        if lead_ndim < 1:
            raise SolverInputError("per-problem boxes need points with a leading batch axis")
        shape = (mins.shape[0],) + (1,) * (lead_ndim - 1) + mins.shape[1:]
        mins, maxs = mins.reshape(shape), maxs.reshape(shape)
        axes = None if axes is None else axes.reshape(shape + (3,))
    return mins, maxs, axes


def _in_box_frames(points, axes):
    """(...,3) points -> (..., K, 3): their coordinates in every box's frame (axes None: the world's)."""
    if axes is None:
        return points[..., None, :]
    return np.sum(points[..., None, :, None] * axes, axis=-2)


def points_inside(points, boxes):
    """(...,3) points, K boxes -> (..., K) bool: point lies in the closed box."""
    p = np.asarray(points, dtype=np.float64)
    mins, maxs, axes = _box_arrays(boxes, p.ndim - 1)
    within = _within(mins, maxs, _in_box_frames(p, axes))  # every axis at once
    return within[..., 0] & within[..., 1] & within[..., 2]


# A segment's step along an axis below which segments_cross divides under np.errstate: beyond it no quotient of
# scene coordinates (below 1e18) overflows.
_TINY_STEP = 1e-290


def segments_cross(a, b, boxes):
    """Segments a->b (...,3), K boxes -> (..., K) bool: the closed segment meets the closed box (slab test).
    A segment with an end inside a box counts as crossing it."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    # Ends of different shapes (one anchor, many candidates) broadcast in the arithmetic: broadcast_arrays cost
    # more than the test on the obstacle response's candidates.
    mins, maxs, axes = _box_arrays(boxes, max(a.ndim, b.ndim) - 1)
    p, q = _in_box_frames(a, axes), _in_box_frames(b, axes)
    if any_set(np.abs(q - p) < _TINY_STEP):  # a division may overflow: quietly (inf, as the test expects)
        with np.errstate(over="ignore"):
            near, far = _slab(mins, maxs, p, q)
    else:  # np.errstate costs as much as the divisions
        near, far = _slab(mins, maxs, p, q)
    # Every axis at once, then over the three by elementwise max/min of their slices: a reduction over a last axis
    # of 3 costs several times more on the obstacle response's hundreds of candidates.
    enter = np.maximum(np.maximum(np.maximum(near[..., 0], near[..., 1]), near[..., 2]), 0.0)
    leave = np.minimum(np.minimum(np.minimum(far[..., 0], far[..., 1]), far[..., 2]), 1.0)
    return enter <= leave


def _within(lo, hi, p):
    """Whether p lies within [lo, hi] on an axis (floats, or arrays of coordinates that broadcast)."""
    return (lo <= p) & (p <= hi)


def _slab(lo, hi, p, q):
    """The part of the segment p -> q within the slab [lo, hi] of an axis, as fractions of the segment (near, far)
    (floats, or arrays of coordinates that broadcast): empty (near > far) where it misses the slab. A segment that
    does not move along the axis is within the slab everywhere or nowhere; a NaN coordinate makes NaN fractions."""
    d = q - p
    flat = d == 0.0
    step = lanes.where(flat, 1.0, d)
    t1, t2 = (lo - p) / step, (hi - p) / step
    near, far = lanes.minimum(t1, t2), lanes.maximum(t1, t2)
    if lanes.any_(flat):
        in_slab = _within(lo, hi, p)
        near = lanes.where(flat, lanes.where(in_slab, -math.inf, math.inf), near)
        far = lanes.where(flat, lanes.where(in_slab, math.inf, -math.inf), far)
    return near, far


def inside(lo, hi, p):
    """Whether the point p (a 3-vector's floats) lies in the closed box [lo, hi]: points_inside's test of one point
    and one box."""
    return _within(lo[0], hi[0], p[0]) & _within(lo[1], hi[1], p[1]) & _within(lo[2], hi[2], p[2])


def crosses(lo, hi, a, b):
    """Whether the closed segment a -> b (3-vectors' floats) meets the closed box [lo, hi]: segments_cross's test
    of one segment and one box, axis by axis (a NaN fraction makes it False, as there), up to the first axis that
    leaves no part of it (the others could only take more)."""
    enter, leave = 0.0, 1.0
    for j in range(3):
        near, far = _slab(lo[j], hi[j], a[j], b[j])
        enter, leave = lanes.maximum(enter, near), lanes.minimum(leave, far)
        if not enter <= leave:
            return False
    return True


def hits(lo, hi, anchor, point, skip_point=None, skip_segment=None):
    """Whether one problem's `point` lies in a box, and whether its segment from `anchor` meets one, of its boxes not
    skipped (lo, hi: lists of their mins and maxs; skip_point, skip_segment: lists of K bools or None): the boxes
    one by one on the point's floats (many problems' points: points_inside and segments_cross test every box at
    once)."""
    found_inside = found_crossing = False
    for k in range(len(lo)):
        if not found_inside and (skip_point is None or not skip_point[k]):
            found_inside = inside(lo[k], hi[k], point)
        if not found_crossing and (skip_segment is None or not skip_segment[k]):
            found_crossing = crosses(lo[k], hi[k], anchor, point)
    return found_inside, found_crossing


def penetrations(positions, segments, boxes):
    """Collision counts of posed chains/trees.

    positions (..., n, 3); segments (m, 2) int joint index pairs. Returns (joints_inside, segments_crossing),
    each (...) int: joints lying in some box, segments meeting some box."""
    p = np.asarray(positions, dtype=np.float64)
    segments = np.asarray(segments, dtype=np.int64).reshape(-1, 2)
    lead = p.shape[:-2]
    if len(boxes) == 0:
        z = np.zeros(lead, dtype=np.int64)
        return z, z.copy()
    inside = points_inside(p, boxes).any(axis=-1).sum(axis=-1)
    if segments.shape[0] == 0:
        return inside, np.zeros(lead, dtype=np.int64)
    # The point axes sit between B and K, so per-problem boxes still pair with the first axis.
    crossing = segments_cross(p[..., segments[:, 0], :], p[..., segments[:, 1], :], boxes).any(axis=-1).sum(axis=-1)
    return inside, crossing
