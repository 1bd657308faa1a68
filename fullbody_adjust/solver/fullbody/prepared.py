"""Work of a solve that depends only on the start pose, done once per start pose and reused while it is the same.

Live Adjust solves every update from one start pose while only the targets move; a frame range solves its
start poses once. What does not depend on the targets is kept here, keyed on the start pose's bytes (heads,
tails, bone X axes) and the settings it depends on, so an entry can never be stale: any change of the pose
is a different key.

  - the limbs' start chains and their reach;
  - the default human limits of every limb (human.default_limits);
  - the model's hierarchy levels (the order the top-down pass visits the bones in), once per model.

The model holds what is kept (BodyModel.memory, memory.SolveMemory), so it lives as long as the caller keeps the
model: the last few start poses of up to _MAX_CACHED_FRAMES frames (a bounded, least recently used dict); a
longer frame range is prepared for its one solve only.

A start pose that is new may still share limbs with a recent one: Adjust Pose solves from the pose the click
before it keyed, in which only the limbs that moved differ. A limb's default limits and its start check are
therefore also kept per limb (SolveMemory.limb_records), keyed on everything they are computed from (human.LimitStart.inputs
and the settings), so a limb whose inputs are the same bit for bit gets the very same limits without
computing them.
"""

import numpy as np

from ..body.model import CHAIN, END, FIXED, ROOT
from ..limits.human import LimitStart
from ..chain.settings import _reach_bounds
from ..errors import SolverInputError
from ..maths.geometry import any_set, norm
from ..obstacles.reach import skeleton_reach

_CAPACITY = 4
_MAX_CACHED_FRAMES = 16
_LIMB_CAPACITY = 32  # limb records: several start poses of a body's six limbs


class PreparedStart:
    """The target-independent part of a solve of `model` from start poses heads, tails (F,J,3)."""

    def __init__(self, model, heads, tails, settings, bone_x_axes):
        self.model = model
        self.levels, self.leaves = levels_of(model)
        # Copies: the caller may change its arrays in place after the solve.
        self._heads, self._tails = heads.copy(), tails.copy()
        self._x_axes = None if bone_x_axes is None else bone_x_axes.copy()
        self._settings = settings
        self._limits = None
        self._records_by_limb = None
        self._chains = None
        self._skeleton_reach = None

    def chains(self):
        """({limb: start chain (F,n,3)}, {limb: reach (F,)}), read-only; the reach is the sum of the segment
        lengths from the base out. SolverInputError for a zero-length segment."""
        if self._chains is None:
            chain0, reach = {}, {}
            for name, limb in self.model.limbs.items():
                joints = limb.joints(self._heads, self._tails)
                lengths = norm(joints[:, 1:] - joints[:, :-1])
                short = lengths <= 1e-12
                if any_set(short):
                    i = int(np.nonzero(short.any(axis=0))[0][0])
                    what = self.model.names[limb.bones[i]]
                    raise SolverInputError(f"{name}: chain segment {i} (from bone {what!r}) has zero length")
                chain0[name], reach[name] = _read_only(joints), _read_only(_reach_bounds(lengths)[0])
            self._chains = chain0, reach
        return dict(self._chains[0]), dict(self._chains[1])  # the caller may add to its dicts

    def skeleton_reach(self):
        """(F,) obstacle_reach.skeleton_reach of the start poses."""
        if self._skeleton_reach is None:
            self._skeleton_reach = _read_only(skeleton_reach(self.model, self._heads, self._tails))
        return self._skeleton_reach

    @property
    def limits(self):
        """{limb name: LimbLimits}: the default human limits (none when the settings turn limits off)."""
        if self._limits is None:
            self._limits = {name: record.limits for name, record in self._records().items()}
        return self._limits

    def _records(self):
        """{limb name: _LimbRecord} of the default limits (none when the settings turn limits off)."""
        if self._records_by_limb is None:
            self._records_by_limb = self._new_records() if self._settings.use_limits else {}
        return self._records_by_limb

    def _new_records(self):
        """The limbs' records, taken from the model's limb records where a limb's inputs are the same."""
        start = LimitStart(self.model, self._heads, self._tails, self._x_axes)
        human = self._settings.human_limits
        remember = self._heads.shape[0] <= _MAX_CACHED_FRAMES  # as prepare(): a long range is solved once
        out = {}
        for limb in self.model.limbs.values():
            make = (lambda limb=limb: _LimbRecord(start.limb_limits(limb, human)))
            out[limb.name] = _kept(self.model.memory.limb_records, _LIMB_CAPACITY, (start.inputs(limb), human), make) \
                if remember else make()
        return out


class _LimbRecord:
    """One limb's default limits at a start pose."""

    def __init__(self, limits):
        self.limits = limits


def prepare(model, heads, tails, settings, bone_x_axes=None) -> PreparedStart:
    """The PreparedStart of these start poses, from the model's memory when the same poses were prepared lately.
    heads, tails (F,J,3) float64; bone_x_axes None, (J,3) or (F,J,3)."""
    x = None if bone_x_axes is None else np.asarray(bone_x_axes, dtype=np.float64)
    if heads.shape[0] > _MAX_CACHED_FRAMES:
        return PreparedStart(model, heads, tails, settings, x)  # a long range is solved once: not remembered
    key = (heads.shape, heads.tobytes(), tails.tobytes(),
           None if x is None else (x.shape, x.tobytes()), settings.use_limits, settings.human_limits)
    return _kept(model.memory.starts, _CAPACITY, key, lambda: PreparedStart(model, heads, tails, settings, x))


def _kept(cache, capacity, key, make):
    """``cache[key]`` (an OrderedDict) when it is there, now the most recently used; else ``make()``, kept under
    ``key``, the least recently used entries beyond ``capacity`` forgotten."""
    value = cache.get(key)
    if value is not None:
        cache.move_to_end(key)
        return value
    value = make()
    cache[key] = value
    while len(cache) > capacity:
        cache.popitem(last=False)
    return value


def _read_only(a):
    a.flags.writeable = False
    return a


def levels_of(model):
    """The model's (levels, leaves) (_levels), computed once per model."""
    memory = model.memory
    if memory.levels is None:
        memory.levels = _levels(model)
    return memory.levels


def _levels(model):
    """The order the top-down pass places the bones that move (not FIXED) in: (levels, leaves).

    levels: by depth in the hierarchy, parents' levels first, the bones on the way to a root, chain or end
    bone: per level the rigidly carried bones (k,) and their parents (k,) (every bone with a parent: chain
    bones are carried first, then placed), and the root, chain and end bones as (bone, parent, role, limb
    name, index in the limb).
    leaves: (bones (k,), anchors (k,)): the other bones (fingers, face, ...), each carried rigidly by its
    nearest ancestor in the levels, all at once after them (a rigid bone turns as its parent does, so a chain
    of rigid bones turns as the bone it hangs from)."""
    parents, roles = model.parents.tolist(), model.roles.tolist()
    placed_roles = (ROOT, CHAIN, END)
    # Bones with a root, chain or end bone at or below them.
    leads = set()
    for j in model.order.tolist()[::-1]:
        if roles[j] in placed_roles or j in leads:
            if parents[j] >= 0:
                leads.add(parents[j])
            leads.add(j)
    depth = {}
    levels = []
    leaves, anchors = [], []
    anchor_of = {}
    for j in model.order.tolist():
        p = parents[j]
        d = depth[j] = depth[p] + 1 if p >= 0 else 0
        if roles[j] == FIXED:
            continue
        if j not in leads and p >= 0:
            anchor_of[j] = anchor_of.get(p, p)
            leaves.append(j)
            anchors.append(anchor_of[j])
            continue
        while len(levels) <= d:
            levels.append(([], [], []))
        rigid, par, limb_bones = levels[d]
        if roles[j] != ROOT and p >= 0:
            rigid.append(j)
            par.append(p)
        if roles[j] in placed_roles:
            limb_bones.append((j, p, roles[j], model.role_limb[j], int(model.role_index[j])))
    levels = [(np.array(r, dtype=np.int64), np.array(p, dtype=np.int64), b) for r, p, b in levels if r or b]
    return levels, (np.array(leaves, dtype=np.int64), np.array(anchors, dtype=np.int64))
