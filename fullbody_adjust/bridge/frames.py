"""Stepping the scene through frames: one pass over a frame range serves every reader (each frame_set
evaluates the whole scene, ~1 ms a frame on a 159-bone rig), and the user's frame comes back afterwards."""

import math


def step_frames(scene, frames):
    """Yield (row, frame) after setting ``scene`` to each of ``frames`` (scene frames, subframes allowed).
    The scene's current frame and subframe are restored afterwards, also on error or an early stop."""
    start_frame, start_subframe = scene.frame_current, scene.frame_subframe
    try:
        for row, frame in enumerate(frames):
            frame = float(frame)
            whole = math.floor(frame)
            scene.frame_set(whole, subframe=frame - whole)
            yield row, frame
    finally:
        scene.frame_set(start_frame, subframe=start_subframe)
