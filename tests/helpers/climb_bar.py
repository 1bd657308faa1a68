"""The bar the climb clip (cmu_01_06) hangs from, built in Blender for tests and benches (needs bpy): a box
around where both of the source's wrists rest while it hangs (both still, above their 75th height
percentile), 2 cm larger on every side."""

import bpy
import numpy as np

HANG_SPEED = 0.1  # m/s: both wrists slower than this are resting on the bar
MARGIN = 0.02


def hanging_frames(wrists, fps):
    """(F,) bool: frames where both wrists (F,2,3, world, Z up) rest high up."""
    speed = np.linalg.norm(np.gradient(wrists, axis=0), axis=-1) * fps
    high = wrists[..., 2] > np.percentile(wrists[..., 2], 75)
    return (speed < HANG_SPEED).all(axis=1) & high.all(axis=1)


def add_bar(wrists, fps):
    """A cube named 'Bar' around the wrists (F,2,3) on the hanging frames; returns it."""
    points = wrists[hanging_frames(wrists, fps)].reshape(-1, 3)
    bpy.ops.mesh.primitive_cube_add()
    bar = bpy.context.active_object
    bar.name = "Bar"
    bar.location = (points.min(axis=0) + points.max(axis=0)) / 2
    bar.scale = (points.max(axis=0) - points.min(axis=0)) / 2 + MARGIN
    bpy.context.view_layer.update()
    return bar
