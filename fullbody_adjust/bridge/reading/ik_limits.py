"""Blender's own joint limits of a rig's bones, read into plain data (solver.rig_limits.BoneLimitSpec): the
per-bone IK settings (``lock_ik_x/y/z``, ``use_ik_limit_x/y/z`` with ``ik_min_*``/``ik_max_*``) and the
enabled Limit Rotation constraints in LOCAL space (``use_limit_x/y/z``, ``min_*``/``max_*``). Both measure the
bone's rotation relative to its rest orientation in its parent's frame, the frame the spec is written in;
where both set an axis the solve keeps to both (a lock wins, ranges intersect).

Limit Rotation constraints in any other owner space (World, Pose, Custom, Local With Parent) are left out:
they bound the bone against a frame that turns with other things than its parent, which a joint limit
between the bone and its parent cannot express. A constraint's Euler order is not read: the solver turns a
ranged bone about one rest axis at a time, and a turn about one axis reads the same angle in every order
(solver/limits/rig_limits.py). A constraint with any influence above 0 counts in full (holding its whole range
keeps the solved pose and the pose Blender evaluates from it the same at any influence).
"""

import numpy as np

from ...solver.limits.human import default_limits
from ...solver.maths.geometry import norm
from ...solver.body.rest_hinges import rest_hinge_axes
from ...solver.limits.rig_limits import AXES, BoneLimitSpec, rig_limits
from ..rig import control_rig
from ..errors import AdjustError


_IK_SETTINGS = tuple(f"{kind}_{a}" for kind in ("lock_ik", "use_ik_limit") for a in "xyz")
_NO_LIMITS = BoneLimitSpec()


def bone_limits(pose_bone):
    """The BoneLimitSpec of one pose bone (its own IK settings and LOCAL Limit Rotation constraints, its rest
    orientation in its parent's). AdjustError (one line) for a constraint range that is empty."""
    if not pose_bone.constraints and not any(getattr(pose_bone, name) for name in _IK_SETTINGS):
        return _NO_LIMITS  # most bones, on every Live update: no need for their rest orientation
    locked = tuple(getattr(pose_bone, f"lock_ik_{a}") for a in "xyz")
    ranges = [(getattr(pose_bone, f"ik_min_{a}"), getattr(pose_bone, f"ik_max_{a}"))
              if getattr(pose_bone, f"use_ik_limit_{a}") else None for a in "xyz"]
    for con in pose_bone.constraints:
        if con.type != 'LIMIT_ROTATION' or not con.enabled or con.influence <= 0.0 or con.owner_space != 'LOCAL':
            continue
        for k, a in enumerate("xyz"):
            if not getattr(con, f"use_limit_{a}"):
                continue
            lo, hi = getattr(con, f"min_{a}"), getattr(con, f"max_{a}")
            if lo > hi:
                raise AdjustError(f"Bone '{pose_bone.name}': Limit Rotation '{con.name}' has its minimum "
                                  f"{AXES[k]} above its maximum: fix the constraint")
            if ranges[k] is not None:
                lo, hi = max(lo, ranges[k][0]), min(hi, ranges[k][1])
                if lo > hi:
                    raise AdjustError(f"Bone '{pose_bone.name}': the {AXES[k]} range of Limit Rotation "
                                      f"'{con.name}' and the bone's other {AXES[k]} limits do not overlap")
            ranges[k] = (lo, hi)
    if not any(locked) and all(r is None for r in ranges):
        return _NO_LIMITS  # constraints of other kinds only (a control rig's bones): the rest orientation unread
    bone = pose_bone.bone
    rest = bone.matrix_local.to_3x3().normalized()
    if bone.parent is not None:
        rest = bone.parent.matrix_local.to_3x3().normalized().inverted() @ rest
    return BoneLimitSpec(locked, tuple(ranges), np.array(rest, dtype=np.float64))


def _limits_of(obj, pose_bone, controls):
    """A bone's own limits; on a control rig (``controls``: control_rig.fk_controls of its chain bones), where
    it sets none, those of the control that poses it."""
    spec = bone_limits(pose_bone)
    if not spec.limits_direction and controls is not None:
        control = controls.get(pose_bone.name)
        if control is not None:
            return bone_limits(obj.pose.bones[control])
    return spec


def hinge_hints(model, rest_matrices, pose_matrices, rest_axes=None):
    """The axes (F,J,3) the default elbow and knee hinges of ``model``'s start poses bend about, in the solve's
    (armature) space, for the solver's ``bone_x_axes``: on each forearm's and shin's row the hinge axis found at
    rest (solver.rest_hinges: from the rest joints and the body's facing, never from bone roll) carried into the
    start pose by the upper arm's / thigh's rotation; on every other row the bone's X axis (unread).
    rest_matrices (J,4,4) (Bone.matrix_local), pose_matrices (F,J,4,4) (PoseBone.matrix); ``rest_axes``: what
    ``rest_axes_of`` gives for them, from a caller that keeps it with the rig (None: found now)."""
    bones, carriers, local = rest_axes_of(model, rest_matrices) if rest_axes is None else rest_axes
    hints = np.array(pose_matrices[..., :3, 0], dtype=np.float64)
    if bones.size:
        turned = pose_matrices[..., carriers, :3, :3]
        turned = turned / norm(np.swapaxes(turned, -1, -2))[..., None, :]  # unit columns (a bone may be scaled)
        hints[..., bones, :] = np.einsum("...ij,...j->...i", turned, local)
    return hints


def rest_axes_of(model, rest_matrices):
    """solver.rest_hinges.rest_hinge_axes of ``model`` at its rest matrices (J,4,4): depends on the rig alone."""
    return rest_hinge_axes(model, rest_matrices[:, :3, 3], rest_matrices[:, :3, :3])


def joint_limits(obj, model, heads, tails, pose_matrices, settings, defaults=None, controls=None, hinge_axes=None):
    """The limits a solve of armature ``obj`` should use: ``defaults`` ({limb: LimbLimits}; None: the default
    human limits, which the solver computes itself) with the rig's own limits of the limbs' chain bones in
    place (solver.rig_limits). heads, tails (F,J,3) and pose_matrices (F,J,4,4) are the start poses of
    ``model``'s bones in the solve's space; ``controls``: on a generated control rig, its chain bones' FK
    controls as rig_cache keeps them (found here when not given); ``hinge_axes`` (F,J,3): what the solve is
    given as bone_x_axes (hinge_hints), for the default limits computed here (None: the bones' X axes).
    Returns ``defaults`` as given when joint limits are off or no chain bone limits its direction, so such a
    rig is solved exactly as without this reading."""
    if not settings.use_limits:
        return defaults
    bones = obj.pose.bones
    chain = [model.names[b] for limb in model.limbs.values() for b in limb.bones]
    if controls is None and control_rig.is_generated_rigify(obj):
        controls = control_rig.fk_controls(obj, chain)
    specs = {name: spec for name in chain if (spec := _limits_of(obj, bones[name], controls)).limits_direction}
    if not specs:
        return defaults
    rotations = pose_matrices[..., :3, :3]
    if defaults is None:
        hinge_axes = rotations[..., 0] if hinge_axes is None else hinge_axes
        defaults = default_limits(model, heads, tails, settings.human_limits, hinge_axes)
    return rig_limits(defaults, model, heads, tails, rotations, specs)
