"""Motion retargeting (paper §6.2.3), the numpy part: a source rig's motion onto a target rig of other
proportions, as a start pose and effector targets for adjust.adjust_frames, and the solved pose back to
bone channels. No bpy: the bridge (bridge/retarget/run.py) reads the rigs and actions and writes the keys.

Conventions. A ``Rig`` holds a skeleton's rest (``Bone.matrix_local``, armature space), its body-model groups
(bone indices), its object's world matrix, each bone's joint end (solver/body/joint_ends.py: positions, lengths,
reaches and segment directions are joints, never the tails an importer left) and each foot's sole (the lowest
skinned vertices of the character's mesh, or the foot's joints without one: soles). Poses are
armature-space pose matrices (F,J,4,4), composed as Blender does (``pose = parent pose @ parent_rest^-1 @
rest @ basis``; a connected bone ignores its location).
Rotation channels follow Blender: Euler angles stored per axis, composed in the mode's order ('XYZ' is
Rz @ Ry @ Rx), quaternions (w, x, y, z), axis-angle (angle, x, y, z).

1. Rotation transfer (``transfer_pose``). Each mapped target bone t takes the WORLD rotation change of its
   source bone s relative to rest, applied to the target's rest turned by an alignment A_t:
       W_t(f) = D_s(f) @ A_t @ W_t_rest,   D_s(f) = W_s(f) @ W_s_rest^-1.
   Limb segments (upper arm, forearm, thigh, shin; hands and feet like the segment they end) are aligned by
   the rest body frames, then the minimal swing taking the target's rest segment direction onto the
   source's, so they point exactly
   where the source's point and T-pose against A-pose or differing bone rolls cancel out. Pelvis, spine,
   clavicles, neck and head are aligned by the rest body frames only (facing and up): there the rigs differ
   by anatomy rather than pose (the CMU clavicle runs from the mid back up to the shoulder, Rigify's along
   the shoulder line), so the target keeps its own spine curve and shoulder line and takes the source's
   changes; the pelvis's change is that of its hip joints' line and its bone's axis across it (a rig that swings
   its hips by moving the thighs' heads turns the target's pelvis too). Pairing (``pair_bones``):
     - root ↔ root;
     - arm and leg chains pair from the effector end (forearm ↔ forearm, upper arm ↔ upper arm, clavicle ↔
       clavicle); a target bone left over (a clavicle the source lacks) rides rigidly on its parent;
     - trunk and neck: bone k of n pairs with bone k of the source when the counts are equal; otherwise by
       proportional position (target bone centre k+½ of n ↔ source position (k+½)·m/n - ½, the rotation
       changes of the two nearest source bones blended);
     - fingers both rigs name (thumb, index, middle, ring, pinky), bone k from the base ↔ bone k, aligned as
       their hand (fingers);
     - hand ↔ hand, foot ↔ foot, head ↔ head (a tiny helper bone pointing anywhere, as the CMU hands, does
       not matter: hands and feet are aligned like their chain's last segment);
   unmapped target bones keep their local transform. The root translates so that the hip centre (midpoint
   of the hip joints) goes where the source's does, scaled about the ground below the rest hips by the
   leg-length ratio (target/source, hip joint to ankle); with the floor a contact, the whole body then up or
   down by as much as puts the target's soles on the floor on the frames the source's are lowest (each rig
   has its own foot below the ankle: an ankle standing higher above its sole than the scaled source's would
   bend the knees to stand; plan._resting_offsets).
2. Effector targets (``plan_retarget``): free of contacts, wrists and ankles go where the transferred pose
   of step 1 puts them, so the solve leaves the limbs at the source's angles. Each effector's contacts come
   from what it touches in the source (contacts.detect_contacts: its slowest point still, speeds per second
   and distances in leg lengths, so any frame rate and size): a contact object's box (hands and feet), the
   floor (feet; the source's soles' lowest points, 2nd percentile; z = 0 where a source without a mesh has
   its lowest joints a little above it), or something raised (a foot still off both). A foot the source
   hardly ever holds still on the floor (an in-place clip) is moved up or down as a whole so its sole is on
   the floor where the source's is lowest. Over a contact the target is held, its offset from the free trajectory blended in and out over
   frames enough to move there without a jump:
     - a foot: it rolls about whichever point of its sole is on the ground on each frame (no sliding),
       centred on its free trajectory, its sole's lowest point exactly on the floor, or on the raised support
       at its world height;
     - a hand on an object: still at the mean of the source's own world positions (exact) or its scaled
       ones (exact=False; scaled about the ground below the hips, by the leg ratio, turned by the heading).
   The heading: the source's motion is turned about world Z by the angle from the source skeleton's rest
   forward to the target's (rig.rest_forward: the toes, else square across the hips, as solver/body/facing.py
   reads them; never the objects' axes), so the target faces its travel as the source faces its own: a source
   walking forward makes the target walk forward, whichever way either character faces in its file.
   A foot rolls onto its toes no further than lifts its ankle as the source's (scaled) and, where it is not
   held, keeps its sole above the floor: turned back toes up about its ankle, so the leg moves as the
   source's where a longer foot would dig into the floor (feet). No foot goes below the floor. The
   whole body then shifts, smoothly, as its held hands and feet moved (on average), and as far again as
   needed to bring every target within its limb's reach less a margin (see ``RetargetSettings.reach_margin``);
   the free trajectories move with it, so only the held limbs are solved.
3. Back to channels (``basis_from_pose`` + ``rotation_channel``): inverse kinematics of the pose matrices,
   rotations in each bone's mode, continuous from frame to frame.
Distances in settings are in source leg lengths (so they hold for any unit and size), durations in seconds.

Where things live: rotation_channels (Blender's rotation channels), rig (Rig, kinematics, measures),
transfer (step 1), contacts (detection and holding), plan (step 2), feet (the feet's
toe roll), foot_pivots (what a planted foot turns about), rise (how far the body rises: in flight, and where a
held foot is nearer its hip than the leg folds), metrics
(measures of the result); this module holds the solve's side (body model, solved pose, motion limits) and
names the whole API in one place.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..body.model import BodyModel
from ..limits.human import HumanLimits, LimbLimits, default_limits
from ..maths.geometry import apply_matrix, cross, dot, norm
from ..limits.joint_limits import HINGE
# The retargeting API in one namespace (the bridge and tests use ``retarget.X``).
from .contacts import (GROUND, OBJECT, RAISED, Contact, ContactDetection, RetargetSettings, box_distance,  # noqa: F401
    detect_contacts, hold, intervals)
from .metrics import angular_roughness, contact_figures, roughness  # noqa: F401
from .plan import RetargetPlan, body_shift, moving_average, plan_retarget, source_floor  # noqa: F401
from .rig import (EFFECTORS, FEET, Rig, ankle_above_sole, basis_from_pose, body_frame, chain_joints, effector_points,  # noqa: F401
    facing_turn, forward_kinematics, hip_centres, leg_length, leg_lengths, rest_forward, rest_points, sole_heights,
    soles_of, unit_columns)
from .transfer import BonePair, carried_bones, pair_bones, transfer_pose, translate_body  # noqa: F401
from ..maths.rotation_channels import (EULER_ORDERS, ROTATION_PROPERTY, axis_angle_to_matrices, basis_matrices,  # noqa: F401
    euler_to_matrices, matrices_to_axis_angle, matrices_to_euler, matrices_to_quaternions, quaternions_of,
    quaternions_to_matrices, rotation_channel, rotation_matrices)


def body_model(rig):
    """(BodyModel, bones): the body model of the rig's mapped bones and their ancestors (``bones``, indices
    into the rig, parents first). The solve needs nothing else: the other bones (fingers, toes, face) ride
    on these and are not written."""
    keep = set()
    for bones in rig.groups.values():
        for b in bones:
            while b >= 0 and b not in keep:
                keep.add(b)
                b = rig.parents[b]
    bones = sorted(keep)
    index = {b: i for i, b in enumerate(bones)}
    model = BodyModel.from_description([rig.names[b] for b in bones],
                                       [index[rig.parents[b]] if rig.parents[b] >= 0 else -1 for b in bones],
                                       {g: [rig.names[b] for b in members] for g, members in rig.groups.items()})
    return model, np.array(bones, dtype=np.int64)


def solved_pose(plan, rotations, heads, bones):
    """Pose matrices (F,J,4,4) after an adjustment of ``bones`` (k indices): their world rotation deltas
    ``rotations`` (F,k,3,3) applied to the start pose's rotations, their heads (F,k,3) as solved (both in the
    solve's space, the target armature). Other bones keep the start pose (they are not written)."""
    solved = plan.start_pose[:, bones]  # a copy (fancy indexing)
    solved[..., :3, :3] = rotations @ np.ascontiguousarray(solved[..., :3, :3])  # strided stacks multiply slowly
    solved[..., :3, 3] = heads
    pose = plan.start_pose.copy()
    pose[:, bones] = solved
    return pose


# --------------------------------------------------------------------------------------------------------
# Joint limits that turn with the motion

# A limb bent by more than this (radians) shows its hinge plane clearly.
_CLEARLY_BENT = 0.2


def motion_limits(model, start_pose, heads, tails, human=HumanLimits(), bone_x_axes=None):
    """Joint limits for adjusting the frames of a motion: human.default_limits of the start poses, except
    each elbow and knee hinge axis, which is fixed in its upper bone's frame (upper arm, thigh) as a real
    elbow or knee is, found from the frames where the limb is clearly bent (their bend axes, weighted by
    how bent). Per-frame axes guessed from each pose alone switch between the bend plane and a fallback as
    a limb straightens, and a knee solved about a switching axis pops sideways. Limbs never clearly bent keep
    the default axes. start_pose (F,J,4,4), heads, tails (F,J,3): the start poses in the solve's space;
    bone_x_axes (F,J,3): what default_limits takes them from for a limb never clearly bent (the bridge's
    rest-found hinge axes; None: the bones' X axes, as a Rigify rig has them)."""
    limits = default_limits(model, heads, tails, human,
                            start_pose[..., :3, 0] if bone_x_axes is None else bone_x_axes)
    for name in ("arm.L", "arm.R", "leg.L", "leg.R"):
        limb, current = model.limbs.get(name), limits.get(name)
        if limb is None or current is None or len(limb.bones) < 2:
            continue
        hinge = len(limb.bones) - 1  # the joint between the last two segments
        if current.limits.kind[hinge] != HINGE:
            continue
        joints = limb.joints(heads, tails)
        upper, lower = joints[:, hinge] - joints[:, hinge - 1], joints[:, hinge + 1] - joints[:, hinge]
        bend = cross(upper, lower)
        size = norm(bend)
        weight = np.where(np.arctan2(size, dot(upper, lower)) > _CLEARLY_BENT, 1.0, 0.0)
        frame = unit_columns(start_pose[:, limb.bones[hinge - 1], :3, :3])  # the upper bone's rotation
        local = np.einsum("fji,fj->i", frame, bend * (weight / np.maximum(size, 1e-300))[:, None])
        if norm(local) < 1e-9:
            continue
        axes = np.broadcast_to(current.limits.hinge_axis, (len(heads),) + current.limits.hinge_axis.shape[-2:]).copy()
        axes[:, hinge] = apply_matrix(frame, local / norm(local))
        limits[name] = LimbLimits(replace(current.limits, hinge_axis=axes), current.parent_direction)
    return limits


def carry_unsolved(rig, pose, bones, basis):
    """Pose matrices (F,J,4,4) where every bone outside ``bones`` (the solved ones) follows its parent as its
    own ``basis`` (J,4,4, or (F,J,4,4) one per frame) says (fingers, toes, heels: as Blender will pose them
    once the solved bones are keyed). ``pose``: as solved_pose gives it; a copy is returned."""
    out = np.array(pose, dtype=np.float64)
    local = rig.relative @ np.asarray(basis, dtype=np.float64)
    locations = local[..., :3, 3]  # a view: (…,J,3)
    locations[..., rig.connected, :] = rig.relative[rig.connected, :3, 3]
    solved = set(int(b) for b in bones)
    for j, p in enumerate(rig.parents):
        if j not in solved and p >= 0:
            out[:, j] = out[:, p] @ local[..., j, :, :]
    return out

