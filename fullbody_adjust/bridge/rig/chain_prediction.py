"""Where a two-bone IK chain goes when its end control moves, predicted without evaluating the rig
(control_match): so that a chain's bend and scale are stepped in the same sweep as its end control, and one
evaluation shows all three.

A chain whose end control moved (and whatever carries its base: the trunk, a clavicle) is predicted from the last
evaluation: its base carried with the control it hangs below, then turned about its first joint as its IK swing
turns to the new end (Rigify's swing bone damped-tracks the IK target, and the IK base hangs below it: the chain's
IK solution rides in that frame); its length is the one its stretch samples give at the new distance
(chain_steps.modelled_length). A chain with a pole (which sets its bend plane) is not predicted. Where that is
wrong, the sweep's closing evaluation finds the error and the next sweep steps the chain from that evaluation:
- the chain's length after the move: a stretchy IK (Rigify's ik_stretch 0.1) sets it by the target's distance,
  modelled from the samples nearest it (chain_steps.modelled_length), which a move far from them leaves wrong;
- the swing's frame before its damped track is carried with what the chain hangs below: a limb parent that copies
  another bone's rotation (Rigify's FK Limb Follow above 0: a Copy Rotation of the root) turns less;
- an IK without a pole starts from its base control's channels each evaluation, and the plane it ends in follows
  the target's distance a little.
"""

import math

import numpy as np

from ...solver.maths import vectors as g
from ...solver.maths.geometry import affine_inverse
from . import chain_steps

def turn_about(point, a, b):
    """4x4 rotation about ``point`` taking direction ``a`` to direction ``b`` by the least turn (a damped track),
    or None when either is degenerate or they are opposite."""
    na, nb = g.norm(a), g.norm(b)
    if min(na, nb) <= 1e-12:
        return None
    a, b = g.divided(a, na), g.divided(b, nb)
    axis = g.cross(a, b)
    sine, cosine = g.norm(axis), g.dot(a, b)
    if cosine <= -1.0 + 1e-9:
        return None
    turn = np.eye(4)
    if sine > 1e-15:
        turn[:3, :3] = g.rotation_about(g.divided(axis, sine), math.atan2(sine, cosine))
    p = np.asarray(point, dtype=np.float64)
    turn[:3, 3] = p - turn[:3, :3] @ p
    return turn


def _tracked(frame, target):
    """``frame`` (4x4) turned about its head by the least turn that points its Y axis at ``target``: Blender's
    damped track."""
    turn = turn_about(frame[:3, 3].tolist(), frame[:3, 1].tolist(), (target - frame[:3, 3]).tolist())
    return None if turn is None else turn @ frame


def predicted_chain(bone, end_head, carry, end_step, swing):
    """(carry, base matrix, end head) of a chain predicted after moves (module notes): ``bone`` its first bone's
    evaluated 4x4 matrix, ``end_head`` its end bone's evaluated head, ``carry`` the motion of what its base hangs
    below, ``end_step`` the end control's whole motion since the evaluation, ``swing`` the (evaluated,
    unconstrained) 4x4 matrices of the bone whose damped track carries the chain (Rigify's IK swing); the returned
    carry is the motion of the chain's base control: the swing's, turned from its unconstrained frame carried with
    the base (not the least turn from the old end to the new one: the two differ by a twist about the new axis,
    which turned the bend plane by up to 2 cm at the elbow in a drag). None where the turn is degenerate (the
    target on the swing's head, or straight behind it): the rig is evaluated first."""
    new_end = end_step[:3, :3] @ end_head + end_step[:3, 3]
    tracked = _tracked(carry @ swing[1], new_end)
    if tracked is None:
        return None
    motion = tracked @ affine_inverse(swing[0])
    return motion, motion @ bone, new_end


def end_correction(chain, end_step, control_head, end_head, samples, scale, length):
    """The armature-space move (3,) of a chain's end control, moved by ``end_step`` (4x4) since the evaluation
    that put it at ``control_head`` and the chain's end at ``end_head``, that puts the end of the predicted
    ``chain`` (predicted_chain, through chain_steps.chain_of) where the step put the end rather than the control:
    the IK's miss at the chain's new stretch (chain_steps.modelled_miss, with its base control's ``scale`` and
    its first bone's rest ``length``) replacing the evaluated one. None without samples, or where the change is
    not a miss's (over a thousandth of ``length``)."""
    bone, end, _length = chain
    base = np.array(chain_steps.head(bone))
    new_end = np.array(end)
    axis = new_end - base
    distance = float(np.linalg.norm(axis))
    miss = chain_steps.modelled_miss(samples, distance, scale, length)
    if miss is None or distance <= 0.0:
        return None
    carried = end_step[:3, :3] @ (end_head - control_head)  # the evaluated miss, as the step carries it
    delta = carried - miss * axis / distance
    return delta if float(np.linalg.norm(delta)) <= 1e-3 * length else None
