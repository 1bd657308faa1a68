# SPDX-License-Identifier: GPL-3.0-or-later
"""``adjust``: the armature's frames solved toward its targets (``bridge.adjustment.adjust_frames``), with the
pose before read for the preview."""

import time

import numpy as np

from ..bridge import adjustment
from ..bridge import files as batch
from ..bridge.reading import start_checks
from ..reporting import preview
from .files import WorkResult, progress_line
from .parser import VARIANT_ENUMS


def adjust(args, context):
    obj = (batch.armature_named(context, args.armature) if args.armature is not None
           else batch.default_armature(context))
    start_checks.check_armature(obj)
    batch.check_mappable(obj, "--armature")
    start, end = batch.frame_range(obj, context.scene, args.frame_start, args.frame_end)
    batch.check_frame_budget(context, obj, start, end)
    options = adjustment.Options(
        variant=VARIANT_ENUMS[args.variant] if args.variant else None, margin=args.margin, tolerance=args.tolerance,
        max_iterations=args.max_iterations, use_joint_limits=False if args.no_limits else None,
        new_action=args.new_action)
    settings = batch.stored_settings(obj)
    settings.update({name: value for name, value in vars(options).items() if name in settings and value is not None})
    original_action = batch.action_name(obj)

    frames = np.arange(start, end + 1, dtype=np.float64)
    shown = frames[preview.pick_snapshots(len(frames), args.preview_frames)]
    if args.preview:  # the pose before, read before anything changes
        before_segments = batch.skeleton_segments(obj, shown)
        before_effectors = batch.effector_positions(obj, frames)
        target_frames = batch.target_positions(context, obj, frames)
        boxes = batch.obstacle_extents(context, obj, shown)

    progress = progress_line(args, len(frames), f"adjust '{obj.name}'")
    started = time.perf_counter()
    outcome = adjustment.adjust_frames(context, obj, start, end, options, progress=progress)
    seconds = time.perf_counter() - started
    progress.finish()

    figure = None
    if args.preview:
        figure = preview.FigureData(
            title=f"ADJUST '{obj.name}'  FRAMES {start}-{end}  {settings['variant']}",
            frames=outcome.frames, effectors=outcome.effectors, error_after=outcome.residuals,
            error_before=np.linalg.norm(before_effectors - target_frames, axis=-1),
            snapshot_frames=shown, after_segments=batch.skeleton_segments(obj, shown),
            before_segments=before_segments, targets=target_frames[np.searchsorted(frames, shown)], boxes=boxes)
    details = {"armature": obj.name, "original_action": original_action,
               "action": outcome.action.name if outcome.action is not None else batch.action_name(obj),
               "settings": settings}
    return WorkResult(outcome=outcome, seconds=seconds, figure=figure, details=details)
