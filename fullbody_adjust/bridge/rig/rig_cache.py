"""Per-armature cache of what a click rebuilds although it depends only on the rig: the stored bone map
(checked against the rig), the solver's BodyModel and the rest data every pose read needs.

An entry is found again only while the armature's fingerprint is unchanged: bone names and parents, connect flags,
rest heads, tails and matrices (read in bulk), the stored map's items, and whether it is a generated control rig
(solved on its skeleton's hierarchy, control_rig). The cached values are a function of exactly these (a stored map
that fits the rig is used as it is, the model is built from the names, parents and map, the rest data and a control
rig's FK controls from the bones), so a hit is never stale. Rotation modes belong to the pose, not the rig:
``Rig.static`` reads them on every call. No setting of ``obj.fullbody_adjust`` other than the map enters the cached
values. Entries are keyed by object name; a renamed or replaced object simply misses once.
"""

from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

from ...solver import SolverInputError
from ...solver.body.model import BodyModel
from ...solver.body.joint_ends import joint_ends
from . import control_rig, mapping
from ..reading import ik_limits, pose
from ..errors import AdjustError

# Armatures remembered at once (a scene rarely has more characters being adjusted).
_CAPACITY = 16

_entries = OrderedDict()  # object name -> _Entry


@dataclass(frozen=True)
class Rig:
    """What a solve needs of the rig that does not change between clicks."""

    bone_map: mapping.BoneMap
    model: BodyModel
    rest: dict  # pose.read_static's fields but the rotation modes
    # On a generated control rig: each limb chain bone's FK control (control_rig.fk_control), or None.
    fk_controls: dict = None
    # (J,3) where each bone ends as a joint, in its own rest frame (solver.joint_ends): what the solve takes for
    # the bones' tails, whatever the importer did with them.
    ends: np.ndarray = None
    # The elbows' and knees' hinge axes found at rest (ik_limits.rest_axes_of), carried into each start pose.
    rest_hinges: tuple = None

    @property
    def controlled(self):
        """A generated control rig (solved on its skeleton, keyed on its controls)."""
        return self.fk_controls is not None

    def static(self, obj):
        """pose.read_static(obj) of this rig, the rotation modes read now."""
        return {**self.rest, "rotation_modes": pose.rotation_modes(obj)}


@dataclass(frozen=True)
class _Entry:
    fingerprint: tuple
    rig: Rig


def rig_of(obj):
    """The armature's Rig, from the cache while its fingerprint is unchanged; otherwise mapped (the map stored
    on the object as ``mapping.ensure_map`` does) and modelled afresh. AdjustError (one line) when the rig
    cannot be mapped or the map does not fit it."""
    fingerprint = _fingerprint(obj)
    entry = _entries.get(obj.name)
    if entry is not None and entry.fingerprint == fingerprint:
        _entries.move_to_end(obj.name)
        return entry.rig
    bone_map = mapping.ensure_map(obj)  # may store a new map, which changes the fingerprint
    rest = pose.read_static(obj)
    del rest["rotation_modes"]
    parents = rest["parents"]
    controlled = control_rig.is_generated_rigify(obj)
    if controlled:  # a control rig is solved on its skeleton (control_rig)
        parents = control_rig.skeleton_parents(rest["names"], parents)
    model = body_model(rest["names"], parents, bone_map)
    fk_controls = None
    if controlled:
        fk_controls = control_rig.fk_controls(obj, [model.names[b] for limb in model.limbs.values()
                                                    for b in limb.bones])
    ends = joint_ends(model.parents, rest["rest_matrices"], pose.rest_tails(obj), model.groups)
    ends.flags.writeable = False
    rig = Rig(bone_map=bone_map, model=model, rest=rest, fk_controls=fk_controls, ends=ends,
              rest_hinges=ik_limits.rest_axes_of(model, rest["rest_matrices"]))
    _entries[obj.name] = _Entry(_fingerprint(obj), rig)
    _entries.move_to_end(obj.name)
    while len(_entries) > _CAPACITY:
        _entries.popitem(last=False)
    return rig


def body_model(names, parents, bone_map):
    """The solver's BodyModel of a rig (bone names, parent indices) under ``bone_map``."""
    try:
        return BodyModel.from_description(tuple(names), np.asarray(parents),
                                          {group: list(bones) for group, bones in bone_map.groups.items()})
    except SolverInputError as ex:
        raise AdjustError(f"Bone mapping does not fit the rig: {ex}") from None


def clear():
    """Forget every entry (e.g. when another file is loaded)."""
    _entries.clear()


def _fingerprint(obj):
    bones = obj.data.bones
    count = len(bones)
    arrays = []
    for prop, size, dtype in (("head_local", 3, np.float32), ("tail_local", 3, np.float32),
                              ("matrix_local", 16, np.float32), ("use_connect", 1, bool)):
        buffer = np.empty(count * size, dtype=dtype)
        bones.foreach_get(prop, buffer)
        arrays.append(buffer.tobytes())
    stored = tuple((item.group, item.bone) for item in obj.fullbody_adjust.bone_map)
    names = tuple(bones.keys())
    return (names, tuple(pose.parent_indices(bones)), *arrays, stored, control_rig.is_generated_rigify(obj))
