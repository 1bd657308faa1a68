"""Stepping the scene through frames: one pass over a frame range serves every reader (each frame_set
evaluates the whole scene, ~1 ms a frame on a 159-bone rig), and the user's frame comes back afterwards."""

import math


_stepping = 0  # how many step_frames passes are under way


def stepping():
    """True while the bridge steps through frames to read them (frame change handlers should stay out)."""
    return _stepping > 0


def step_frames(scene, frames):
    """Yield (row, frame) after setting ``scene`` to each of ``frames`` (scene frames, subframes allowed).
    The scene's current frame and subframe are restored afterwards, also on error or an early stop; that
    last frame change is an ordinary one (``stepping()`` is False again)."""
    global _stepping
    start_frame, start_subframe = scene.frame_current, scene.frame_subframe
    _stepping += 1
    try:
        for row, frame in enumerate(frames):
            frame = float(frame)
            whole = math.floor(frame)
            scene.frame_set(whole, subframe=frame - whole)
            yield row, frame
    finally:
        _stepping -= 1
        scene.frame_set(start_frame, subframe=start_subframe)
