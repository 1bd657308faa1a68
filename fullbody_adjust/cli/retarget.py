# SPDX-License-Identifier: GPL-3.0-or-later
"""``retarget --source ARMATURE``: one armature's motion onto another (``bridge.retarget.retarget``); the
--target and --contacts checks are shared with a batch of clip files (``clips``)."""

import time

import numpy as np

from ..bridge import files as batch
from ..bridge.reading import start_checks
from ..bridge.retarget import root_motion
from ..bridge.retarget.run import retarget as retarget_motion
from ..reporting import preview
from ..solver.retarget.root_motion import DEFAULT_SMOOTHING
from .files import CommandError, WorkResult, progress_line


def retarget_target(args, context):
    """A retarget's --target armature, checked as retargeting onto it needs (one line otherwise; its
    --root-motion and --root-bone too), and its
    --contacts as the bridge takes them ('ground', or ('object', Object))."""
    target = batch.armature_named(context, args.target, "--target")
    start_checks.check_armature(target)
    batch.check_mappable(target, "--target")
    if args.groups is not None and args.root_motion not in (None, "hips"):
        raise CommandError(f"--root-motion {args.root_motion} moves every bone, so it cannot go with --groups (a "
                           f"partial retarget keeps the target's own keys elsewhere)")
    # a batch's too, before any clip starts
    root_motion.check(target, args.root_motion, args.root_bone, smoothing=args.root_smoothing)
    contacts = [kind if name is None else (kind, batch.object_named(context, name, "--contacts object"))
                for kind, name in args.contacts or [("ground", None)]]
    return target, contacts


def root_smoothing(mode, seconds):
    """The root smoothing a retarget in root motion ``mode`` uses (seconds; None where the travel stays on the
    hips): as given, else the default."""
    if mode in (None, "hips"):
        return None
    return DEFAULT_SMOOTHING if seconds is None else float(seconds)


def retarget(args, context):
    source = batch.armature_named(context, args.source, "--source")
    batch.check_mappable(source, "--source")
    target, contacts = retarget_target(args, context)
    if source == target:
        raise CommandError("--source and --target are the same armature")
    start, end = batch.frame_range(source, context.scene, args.frame_start, args.frame_end, within_scene=True)
    batch.check_frame_budget(context, target, start, end)

    frames = np.arange(start, end + 1, dtype=np.float64)
    shown = frames[preview.pick_snapshots(len(frames), args.preview_frames)]
    progress = progress_line(args, len(frames), f"retarget '{source.name}' -> '{target.name}'")
    started = time.perf_counter()
    outcome = retarget_motion(context, source, target, start, end, contacts=contacts, new_action=args.new_action,
                              floor=args.floor, progress=progress, mirror=args.mirror, groups=args.groups,
                              root_motion=args.root_motion, root_bone=args.root_bone,
                              root_smoothing=args.root_smoothing)
    seconds = time.perf_counter() - started
    progress.finish()

    figure = None
    if args.preview:  # the source's motion in grey, the target's in blue, with the targets the retarget set
        planned = getattr(outcome, "targets", None)  # (F,E,3) world
        figure = preview.FigureData(
            title=f"RETARGET '{source.name}' TO '{target.name}'  FRAMES {start}-{end}",
            frames=outcome.frames, effectors=outcome.effectors, error_after=outcome.contact_error,
            error_before=outcome.contact_error_before, plot_title="CONTACT ERROR (SCENE UNITS) OVER FRAMES",
            snapshot_frames=shown, before_segments=batch.skeleton_segments(source, shown),
            after_segments=batch.skeleton_segments(target, shown),
            targets=None if planned is None else planned[np.searchsorted(outcome.frames, shown)])
    action = getattr(outcome, "action", None)
    details = {"source": source.name, "target": target.name, "armature": target.name,
               "contacts": outcome.contact_report, "floor": args.floor, "root_motion": args.root_motion,
               "root_smoothing": root_smoothing(args.root_motion, args.root_smoothing), "mirror": bool(args.mirror),
               "groups": list(args.groups) if args.groups is not None else None,
               "action": action.name if action is not None else batch.action_name(target)}
    return WorkResult(outcome=outcome, seconds=seconds, figure=figure, details=details)
