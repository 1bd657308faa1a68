"""The space Adjust Pose solves in: the armature's own space (its object transform undone) scaled to world units,
so bone lengths are rigid there even under a non-uniform object scale while every distance the solver reports is
in world units; the settings carried into it, points carried back, and the obstacles' boxes built in it."""

from dataclasses import replace

import numpy as np

from ...solver import Boxes
from ...solver.maths.geometry import affine_inverse, norm
from ...solver.body.joint_ends import end_points


def in_solve_units(settings, scales, unit):
    """``settings`` (world units) for a solve in the solve space (solve_space): the tolerance shrunk by the
    largest object scale, so a target met in the solve space is met in the world; the obstacle margin grown by
    the smallest, so the clearance kept in the world is at least the margin. Under a uniform object scale both
    stay as they are. ``scales``: object_scales; ``unit`` (F,): solve_space's."""
    largest, smallest = scales
    chain = settings.chain
    chain = replace(chain, tolerance=chain.tolerance * float(unit.min()) / largest,
                    margin=chain.margin * float(unit.max()) / smallest)
    return replace(settings, chain=chain)


def object_scales(snapshot):
    """(largest, smallest) axis scale of the object's world matrix over the snapshot's frames."""
    scales = norm(np.swapaxes(snapshot.matrix_world[:, :3, :3], -1, -2))  # (F,3)
    return float(scales.max()), float(scales.min())


def solve_space(snapshot, ends):
    """(to_solve (F,4,4), heads, tails (F,B,3), unit (F,)), read-only (they are kept with the snapshot): the solve
    runs in the armature's space scaled by ``unit``, the world length of one armature unit (the cube root of the
    object scale's volume), so that bone lengths are rigid there even under a non-uniform object scale, while every
    distance the solver reports (residuals, reaches, in its reasons) is in world units: an armature in centimetres
    under an object scale of 0.01 is solved in metres. The tails are where the bones end as joints (``ends``,
    rig_cache.Rig.ends), not where the importer left them."""
    unit = np.cbrt(np.linalg.det(snapshot.matrix_world[:, :3, :3]))
    to_solve = unit[:, None, None] * affine_inverse(snapshot.matrix_world)
    to_solve[:, 3] = (0.0, 0.0, 0.0, 1.0)
    out = (to_solve, transform(to_solve, snapshot.heads),
           unit[:, None, None] * end_points(snapshot.pose_matrices, ends), unit)
    for array in out:
        array.flags.writeable = False
    return out


def armature_units(points, unit):
    """Solve-space points (F,...,3) in armature units (solve_space's ``unit`` (F,))."""
    return points / unit.reshape((-1,) + (1,) * (points.ndim - 1))


def transform(matrices, points):
    """points (F,...,3) through (F,4,4) matrices."""
    m = matrices.reshape(matrices.shape[0], *([1] * (points.ndim - 2)), 4, 4)
    return np.einsum("...ij,...j->...i", m[..., :3, :3], points) + m[..., :3, 3]


def armature_boxes(world_corners, to_arm, centre, radius):
    """The obstacles' boxes in armature space from their world corners (F,K,8,3) in bound_box order: each the
    mesh's own (oriented) box, as the user sees it; None when there are none. Boxes no bone can reach (outside the
    ball `centre` (F,3), `radius` (F,) on every frame: solver.obstacle_reach) are left out before they are built:
    a box built from 8 corners lies within sqrt(3) times their farthest distance from their mean (along each of its
    axes it spans their projections), so one whose ball is outside is outside. (The solver then leaves out, on the
    built boxes' bounds, what this looser test kept.)

    One frame's last corners and boxes are kept (_last_boxes): Live builds the same boxes on every update while
    only the targets move, and so do clicks while the obstacles stay."""
    one = world_corners.shape[0] == 1
    last = _last_boxes if one else {}  # a frame range's are built for its one solve
    key = (to_arm.tobytes(), world_corners.shape, world_corners.tobytes()) if one else None
    if key is None or last.get("key") != key:
        corners = transform(to_arm, world_corners)
        mean = corners.mean(axis=2)
        last.clear()
        size = np.sqrt(3.0) * norm(corners - mean[:, :, None]).max(axis=2)
        last.update(key=key, corners=corners, mean=mean, size=size)
    keep = (norm(last["mean"] - centre[:, None]) - last["size"] <= radius[:, None]).any(axis=0)
    if not keep.any():
        return None
    if last.get("kept") is None or not np.array_equal(last["kept"], keep):
        last.update(kept=keep, boxes=Boxes.from_box_corners(last["corners"][:, keep]))
    return last["boxes"]


# armature_boxes' last frame: its key (the armature transform and the world corners, as bytes), the corners in
# armature space with their means and sizes, and the Boxes built from those kept (immutable: shared by the solves).
_last_boxes = {}


def size_of(points):
    """The rig's size: the largest extent of its points (..., 3) along an axis."""
    return max(float(np.ptp(points.reshape(-1, 3), axis=0).max()), 1e-12)


def world_size(snapshot):
    """The rig's size in the world (size_of of its heads), kept with the snapshot."""
    return snapshot.derived("world size", lambda: size_of(snapshot.heads))
