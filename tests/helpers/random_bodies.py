"""Random full-body problems on the Rigify human metarig (tests/helpers/metarig.py), for bench/fuzz.py and the solver
tests: a batch is a short "clip" of one random problem whose frames differ by a small jitter (of the start pose, the
targets and the boxes), so a batch's frames cost alike unless the solver has a bad case among them.

A problem: a start pose made by random local rotations of every bone down the hierarchy (bone lengths kept), turned
about the vertical and moved, at a scale from 1e-3 to 1e3; per effector (EFFECTORS) a target of one KIND; random
boxes (none, or up to 8 per frame) near the body's joints, the targets, the root; some of them around a target or a
limb's base."""

from dataclasses import dataclass

import numpy as np

from fullbody_adjust.solver.body.model import LIMB_OF_EFFECTOR
from fullbody_adjust.solver.obstacles.boxes import Boxes
from tests.helpers import metarig

EFFECTORS = metarig.EFFECTORS
# Target kinds: no target (a NaN row), its own joint (the target met by the start), within reach, about the reach's
# edge, beyond reach (up to 100 reaches away), at the root (the pelvis head), at its limb's base (shoulder, hip,
# neck: no distance from it), the same point as another effector's target, its own joint moved by 1e-12.
KINDS = ("none", "still", "near", "edge", "far", "root", "base", "coincident", "tiny")


@dataclass
class Batch:
    """F frames of one problem: start poses (F,J,3) and bone X axes, targets (F,E,3) (a NaN row: none), obstacles
    (Boxes per frame, or None), each effector's target kind (E,), the scale (the body's height) and the jitter."""

    heads: np.ndarray
    tails: np.ndarray
    x_axes: np.ndarray
    targets: np.ndarray
    obstacles: Boxes
    kinds: tuple
    height: float
    jitter: float


def rotations(rng, n, max_angle):
    """n random rotation matrices (n,3,3) about random axes by angles up to `max_angle` (each its own bound)."""
    axis = rng.normal(size=(n, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    angle = rng.uniform(0.0, 1.0, n) * max_angle
    k = np.zeros((n, 3, 3))
    k[:, 0, 1], k[:, 0, 2], k[:, 1, 2] = -axis[:, 2], axis[:, 1], -axis[:, 0]
    k -= k.transpose(0, 2, 1)
    s, c = np.sin(angle)[:, None, None], np.cos(angle)[:, None, None]
    return np.eye(3) + s * k + (1.0 - c) * (k @ k)


def posed(model, heads, tails, x_axes, turns):
    """Heads, tails and X axes (F,J,3) of the rest pose with each bone turned by `turns` (F,J,3,3) relative to its
    parent (forward kinematics about each bone's head, down model.order): every bone keeps its length and its
    offset from its parent's head."""
    F = turns.shape[0]
    world = np.empty_like(turns)
    h = np.empty((F,) + heads.shape)
    t, x = np.empty_like(h), np.empty_like(h)
    parents = model.parents.tolist()
    for j in model.order.tolist():
        p = parents[j]
        if p < 0:
            world[:, j] = turns[:, j]
            h[:, j] = heads[j]
        else:
            world[:, j] = world[:, p] @ turns[:, j]
            h[:, j] = h[:, p] + np.einsum("fij,j->fi", world[:, p], heads[j] - heads[p])
        t[:, j] = h[:, j] + np.einsum("fij,j->fi", world[:, j], tails[j] - heads[j])
        x[:, j] = np.einsum("fij,j->fi", world[:, j], x_axes[j])
    return h, t, x


def _unit(rng, n):
    d = rng.normal(size=(n, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def batch(rng, rig, frames, kinds=None, boxes=None, scale=None, jitter=None):
    """One random Batch of `frames` frames on `rig` (metarig.load()); `kinds` (E,) of KINDS, `boxes` (their number,
    0: none), `scale` (the body's height) and `jitter` (relative to it) drawn when None."""
    model, h0, t0, x0 = rig
    J, E = len(model.names), len(EFFECTORS)
    kinds = tuple(rng.choice(KINDS, E)) if kinds is None else tuple(kinds)
    boxes = int(rng.choice([0, 0, 1, 3, 8])) if boxes is None else boxes
    rest_height = float(np.ptp(np.concatenate([h0, t0])[:, 2]))
    height = 10.0 ** rng.uniform(-3.0, 3.0) if scale is None else scale
    jitter = 10.0 ** rng.uniform(-9.0, -2.0) if jitter is None else jitter
    # The problem's pose: random local turns (up to 0.6 rad; the root any way about the vertical), then each frame's
    # own small turns on top.
    base_turns = rotations(rng, J, rng.uniform(0.0, 0.6, J))
    spin = rotations(rng, 1, np.array([np.pi]))[0]
    frame_turns = rotations(rng, frames * J, np.full(frames * J, jitter)).reshape(frames, J, 3, 3)
    h, t, x = posed(model, h0, t0, x0, base_turns[None] @ frame_turns)
    s = height / rest_height
    offset = rng.normal(size=3) * height * rng.choice([0.0, 1.0, 30.0])
    h = np.einsum("ij,fkj->fki", spin, h) * s + offset
    t = np.einsum("ij,fkj->fki", spin, t) * s + offset
    x = np.einsum("ij,fkj->fki", spin, x)
    targets = np.full((frames, E, 3), np.nan)
    for k, (e, kind) in enumerate(zip(EFFECTORS, kinds)):
        limb = model.limbs[LIMB_OF_EFFECTOR[e]]
        joints = limb.joints(h, t)
        reach = np.linalg.norm(np.diff(joints, axis=1), axis=2).sum(axis=1)[:, None]
        direction = _unit(rng, 1)
        own, base = joints[:, -1], joints[:, 0]
        targets[:, k] = {
            "none": np.nan, "still": own, "tiny": own + 1e-12 * height * _unit(rng, 1),
            "near": base + direction * reach * rng.uniform(0.05, 0.98),
            "edge": base + direction * reach * (1.0 + rng.choice([-1e-9, 0.0, 1e-9, 1e-6])),
            "far": base + direction * reach * 10.0 ** rng.uniform(0.05, 2.0),
            "root": h[:, model.root], "base": base, "coincident": np.nan}[kind]
    for k, kind in enumerate(kinds):  # the same point as another effector's target (or its own joint)
        if kind == "coincident":
            others = [i for i in range(E) if i != k and kinds[i] not in ("none", "coincident")]
            if others:
                targets[:, k] = targets[:, rng.choice(others)]
            else:
                targets[:, k] = model.limbs[LIMB_OF_EFFECTOR[EFFECTORS[k]]].end_point(h, t)
    moving = np.isfinite(targets[..., 0]) & (np.array(kinds) != "still")
    targets += np.where(moving[..., None], rng.normal(size=targets.shape) * jitter * height, 0.0)
    obstacles = None
    if boxes:
        obstacles = _boxes(rng, boxes, frames, h, t, targets, model, height, jitter)
    return Batch(h, t, x, targets, obstacles, kinds, height, jitter)


def _boxes(rng, count, frames, h, t, targets, model, height, jitter):
    """`count` boxes per frame: about a random joint (most), a target, the root or a limb's base; half sizes from
    1/300 to 1/3 of the height; moved a little per frame."""
    points = np.concatenate([h[0], t[0]])
    set_targets = targets[0][np.isfinite(targets[0, :, 0])]
    centres, halves = [], []
    for _ in range(count):
        where = rng.choice(["joint", "target", "root", "base"], p=[0.6, 0.2, 0.1, 0.1])
        if where == "target" and len(set_targets):
            centre = set_targets[rng.integers(len(set_targets))]
        elif where == "root":
            centre = h[0, model.root]
        elif where == "base":
            limb = model.limbs[rng.choice(list(model.limbs))]
            centre = h[0, limb.bones[0]]
        else:
            centre = points[rng.integers(len(points))]
        half = height * 10.0 ** rng.uniform(-2.5, -0.5, 3)
        centres.append(centre + rng.normal(size=3) * half * rng.choice([0.0, 1.0]))
        halves.append(half)
    centres, halves = np.array(centres), np.array(halves)
    drift = rng.normal(size=(frames, count, 3)) * jitter * height
    return Boxes(centres[None] - halves[None] + drift, centres[None] + halves[None] + drift)
