"""A rig as plain data for bone mapping (no bpy): bone names, parents, rest heads and tails in armature space,
and the hierarchy questions mapping asks of it (subtrees, paths, extents). Side markers in names are read here
too: ``L``/``R``/``Left``/``Right`` as whole name tokens, split at ``. _ - :``, spaces, digits and camelCase.

Joints are bone heads. Importers put tails anywhere (Blender's glTF importer often far past the next joint, its
FBX importer along each bone's Y axis), so no joint, length or extent here is read from a tail, with one
exception: where nothing follows a bone, its tail is the only sign of how far it goes (a fingertip, a big head
with nothing above it). So how high a subtree reaches (``_Skeleton.top``) counts tails within the rig's size of
their heads, and a leaf's length (``_Skeleton.leaf_reach``) is its tail's distance when that is no more than
twice the step from its parent's head (a BVH End Site, a glTF leaf pointing on as its parent did), else 0.
"""

from dataclasses import dataclass, field
from functools import cached_property
import math
import re

import numpy as np

from ..solver.body.joint_ends import joint_ends

MIDLINE = 0.01  # a bone whose head is this close (fraction of the height) to the body's middle plane is at it


@dataclass(frozen=True, eq=False)
class RigDescription:
    """A rig as plain data: N bones with names, parent indices (-1: none), rest heads and tails (N, 3) in
    armature space, the rig's name (for messages) and ``orientation``, the (3, 3) rotation from armature
    space to the world (z up); identity unless the armature object is rotated."""

    names: tuple
    parents: np.ndarray
    heads: np.ndarray
    tails: np.ndarray
    name: str = "Armature"
    orientation: np.ndarray = field(default_factory=lambda: np.eye(3))

    def __post_init__(self):
        names = tuple(str(n) for n in self.names)
        n = len(names)
        parents = np.asarray(self.parents, dtype=np.int64).reshape(-1)
        heads = np.asarray(self.heads, dtype=np.float64).reshape(-1, 3) if n else np.zeros((0, 3))
        tails = np.asarray(self.tails, dtype=np.float64).reshape(-1, 3) if n else np.zeros((0, 3))
        orientation = np.asarray(self.orientation, dtype=np.float64)
        if len(set(names)) != n:
            duplicate = next(x for x in names if names.count(x) > 1)
            raise ValueError(f"rig '{self.name}': bone name '{duplicate}' is used twice")
        if parents.shape != (n,) or heads.shape != (n, 3) or tails.shape != (n, 3):
            raise ValueError(f"rig '{self.name}': {n} names but parents {parents.shape}, heads {heads.shape}, "
                             f"tails {tails.shape}")
        if n and (parents.min() < -1 or parents.max() >= n):
            raise ValueError(f"rig '{self.name}': parent index out of range -1..{n - 1}")
        if not (np.isfinite(heads).all() and np.isfinite(tails).all()):
            raise ValueError(f"rig '{self.name}': bone positions have NaN/inf")
        if orientation.shape != (3, 3) or not np.isfinite(orientation).all():
            raise ValueError(f"rig '{self.name}': orientation must be a finite 3x3 matrix")
        for attr, value in (("names", names), ("parents", parents), ("heads", heads), ("tails", tails),
                            ("orientation", orientation)):
            object.__setattr__(self, attr, value)
        self._skeleton  # reject cycles now rather than at first use

    def __len__(self):
        return len(self.names)

    def index(self, bone):
        """Index of ``bone``; KeyError naming it when the rig has no such bone."""
        try:
            return self._index_of[bone]
        except KeyError:
            raise KeyError(f"rig '{self.name}' has no bone '{bone}'") from None

    @cached_property
    def _index_of(self):
        return {n: i for i, n in enumerate(self.names)}

    @cached_property
    def _skeleton(self):
        return _Skeleton(self)


_TOKEN = re.compile(r"[A-Z]+(?=[A-Z][a-z])|[A-Z]?[a-z]+|[A-Z]+|\d+")
_SIDE_TOKENS = {"l": "L", "left": "L", "r": "R", "right": "R"}


def side_of_name(name):
    """'L', 'R' or None from the side markers in a bone name (see the module docstring)."""
    sides = {_SIDE_TOKENS[t] for t in (tok.lower() for tok in _TOKEN.findall(name)) if t in _SIDE_TOKENS}
    return sides.pop() if len(sides) == 1 else None


class _Skeleton:
    """Derived data of a RigDescription: children, pre-order, world-oriented positions, sizes."""

    def __init__(self, desc):
        n = len(desc.names)
        self.desc = desc
        self.children = [[] for _ in range(n)]
        roots = []
        for i, p in enumerate(desc.parents.tolist()):
            (roots if p < 0 else self.children[p]).append(i)
        self.parent = desc.parents.tolist()
        self.tin = [-1] * n
        self.tout = [0] * n
        self.depth = [0] * n
        order = []
        for r in roots:
            stack = [(r, False)]
            while stack:
                b, done = stack.pop()
                if done:
                    self.tout[b] = len(order)
                    continue
                self.tin[b] = len(order)
                order.append(b)
                stack.append((b, True))
                for c in reversed(self.children[b]):
                    self.depth[c] = self.depth[b] + 1
                    stack.append((c, False))
        if len(order) < n:
            looped = next(i for i in range(n) if self.tin[i] < 0)
            raise ValueError(f"rig '{desc.name}': bone '{desc.names[looped]}' is its own ancestor")
        self.order = np.array(order, dtype=np.int64)
        self.heads = desc.heads @ desc.orientation.T
        self.tails = desc.tails @ desc.orientation.T
        # Sizes from the joints (heads); tails only when the heads give none (a single bone).
        points = self.heads if n > 1 and np.ptp(self.heads, axis=0).any() else \
            (np.concatenate([self.heads, self.tails]) if n else np.zeros((1, 3)))
        extent = points.max(axis=0) - points.min(axis=0)
        self.size = float(np.linalg.norm(extent)) or 1.0
        self.height = float(extent[2]) or self.size
        self.tiny = 1e-6 * self.size
        self.name_sides = [side_of_name(name) for name in desc.names]
        # Highest point of each bone's subtree: its heads, and its tails within the rig's size of their heads.
        reach = np.linalg.norm(self.tails - self.heads, axis=1) if n else np.zeros(0)
        tail_z = np.where(reach <= self.size, self.tails[:, 2], -np.inf) if n else np.zeros(0)
        self.top = np.maximum(self.heads[:, 2], tail_z) if n else np.zeros(0)
        for b in reversed(order):
            for c in self.children[b]:
                self.top[b] = max(self.top[b], self.top[c])
        # Leaf bones FBX exporters add at each chain's end ("<parent>_end"): markers of where it ends, not bones.
        self.end_marker = [not self.children[b] and self.parent[b] >= 0
                           and desc.names[b] == desc.names[self.parent[b]] + "_end" for b in range(n)]
        self.leaf_reach = np.zeros(n)
        for b in range(n):
            p = self.parent[b]
            if not self.children[b] and p >= 0:
                step = float(np.linalg.norm(self.heads[b] - self.heads[p]))
                self.leaf_reach[b] = reach[b] if reach[b] <= 2.0 * step else 0.0

    @cached_property
    def ends(self):
        """(N,3) where each bone ends as a joint (solver.joint_ends without a bone map: its only child's head,
        else its tail shortened where implausibly long), world-oriented like ``heads``. A hand-less arm's wrist
        is its forearm's end."""
        rest = np.tile(np.eye(4), (len(self.parent), 1, 1))
        rest[:, :3, 3] = self.heads
        return self.heads + joint_ends(self.desc.parents, rest, self.tails)

    def subtree(self, b):
        return self.order[self.tin[b]:self.tout[b]]

    def is_ancestor(self, a, b):
        """a is a proper ancestor of b."""
        return a != b and self.tin[a] <= self.tin[b] < self.tout[a]

    def path(self, a, b):
        """Bones from a down to b, both included (a must be b or an ancestor of b)."""
        out = [b]
        while out[-1] != a:
            out.append(self.parent[out[-1]])
        return out[::-1]

    def lca(self, a, b):
        while not (a == b or self.is_ancestor(a, b)):
            a = self.parent[a]
            if a < 0:
                return -1
        return a

    def longest_path(self, b):
        """From b to the leaf that makes the longest run of joints, head to head (fingers beat twist bones)."""
        best = {}
        for x in reversed(self.subtree(b).tolist()):
            kids = self.children[x]
            if not kids:
                best[x] = (float(self.leaf_reach[x]), None)
                continue
            c = max(kids, key=lambda c: float(np.linalg.norm(self.heads[c] - self.heads[x])) + best[c][0])
            best[x] = (float(np.linalg.norm(self.heads[c] - self.heads[x])) + best[c][0], c)
        out = [b]
        while best[out[-1]][1] is not None:
            out.append(best[out[-1]][1])
        return out


def angle_between(v, w):
    """Angle between two vectors (0 when either has no length)."""
    norm = float(np.linalg.norm(v) * np.linalg.norm(w))
    if norm == 0.0:
        return 0.0
    return math.acos(max(-1.0, min(1.0, float(np.dot(v, w)) / norm)))


DOWN = np.array([0.0, 0.0, -1.0])
UP = np.array([0.0, 0.0, 1.0])
