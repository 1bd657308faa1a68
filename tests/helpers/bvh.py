"""A small numpy BVH reader for tests and benchmarks (no bpy).

`read_bvh(path, scale)` parses HIERARCHY + MOTION; `BvhClip.forward_kinematics()` gives world joint positions
and rotations per frame (rotation channels composed in the order the file declares them, e.g. ZXY);
`BvhClip.bones()` turns joints into bones the way Blender's BVH importer (io_anim_bvh) does, so the solver is
tested on the same bones the bridge will read from an imported clip:
  - a joint with one child: tail = that child's head;
  - several children: tail = the mean of the children's heads;
  - no child: tail = its End Site (or the head, if none);
  - a tail within 0.001 file units of its head (CMU's Hips, Spine1 and hands, whose children all sit at offset 0)
    is moved +0.1 file units along the joint's local Y, as Blender does. So no bone has zero length; group
    chains skip such tiny bones where it matters (see CMU_GROUPS).
Positions come out in file units times `scale` (CMU: 0.056444 m per unit), in the file's own axes (Y up).
"""
from __future__ import annotations

from dataclasses import dataclass
import os
from pathlib import Path

import numpy as np

CMU_SCALE = 0.056444  # metres per CMU BVH unit (tests/data/mocap/README.md)
# The CMU clips the tests and benches use ship with the repository; FBA_MOCAP_DIR overrides.
MOCAP_DIR = Path(os.environ.get("FBA_MOCAP_DIR", Path(__file__).resolve().parents[1] / "data" / "mocap"))


def body_groups(sides, *, root, trunk, arm, hand, leg, foot, head):
    """A body-model bone map {group: [bone, ...]} of a skeleton: ``{side}`` in the arm, hand, leg and foot names
    becomes each of ``sides`` (left spelling, right spelling), for groups "arm.L" and "arm.R"..."""
    sided = {"arm": arm, "hand": hand, "leg": leg, "foot": foot}
    groups = {"root": root, "trunk": trunk}
    for kind, names in sided.items():
        for suffix, side in zip(("L", "R"), sides):
            groups[f"{kind}.{suffix}"] = [name.format(side=side) for name in names]
    groups["head"] = head
    return groups


# Body-model groups for the MotionBuilder-style CMU skeleton.
CMU_GROUPS = body_groups(("Left", "Right"), root=["Hips"], trunk=["LowerBack", "Spine", "Spine1"],
                         arm=["{side}Shoulder", "{side}Arm", "{side}ForeArm"], hand=["{side}Hand"],
                         leg=["{side}UpLeg", "{side}Leg"], foot=["{side}Foot"], head=["Neck", "Neck1", "Head"])
# ... and for the Daz-skeleton BVH (cmu_daz_02_01_walk.bvh), as bone_mapping/presets.toml maps it.
DAZ_GROUPS = body_groups(("l", "r"), root=["hip"], trunk=["abdomen", "chest"],
                         arm=["{side}Collar", "{side}Shldr", "{side}ForeArm"], hand=["{side}Hand"],
                         leg=["{side}Thigh", "{side}Shin"], foot=["{side}Foot"], head=["neck", "head"])

CMU_CLIPS = (
    "cmu_07_01_walk.bvh",
    "cmu_02_06_pickup_f0-1349.bvh",
    "cmu_01_06_climb_sit_f360-1559.bvh",
    "cmu_02_04_jump.bvh",
    "cmu_05_02_dance.bvh",
)

_AXIS = {"x": 0, "y": 1, "z": 2}


@dataclass(frozen=True)
class BvhClip:
    names: tuple[str, ...]
    parents: np.ndarray  # (J,) int, -1 for the root
    offsets: np.ndarray  # (J,3) rest offsets from the parent, scaled
    end_sites: dict  # joint index -> (3,) End Site offset, scaled
    channels: tuple[tuple[str, ...], ...]  # per joint, as declared, lower case: ('xposition', 'zrotation', ...)
    motion: np.ndarray  # (F, C) raw channel values (rotations in degrees, positions unscaled)
    frame_time: float
    scale: float

    @property
    def frame_count(self) -> int:
        return self.motion.shape[0]

    def children(self, j: int) -> list[int]:
        return [int(c) for c in np.flatnonzero(self.parents == j)]

    def forward_kinematics(self, frames=None) -> tuple[np.ndarray, np.ndarray]:
        """World joint positions (F,J,3) and world rotations (F,J,3,3) for the given frame indices (0-based)."""
        motion = self.motion if frames is None else self.motion[np.asarray(frames)]
        n_frames, n_joints = motion.shape[0], len(self.names)
        positions = np.empty((n_frames, n_joints, 3))
        rotations = np.empty((n_frames, n_joints, 3, 3))
        column = 0
        for j, chans in enumerate(self.channels):
            local_t = np.broadcast_to(self.offsets[j], (n_frames, 3)).copy()
            local_r = np.broadcast_to(np.eye(3), (n_frames, 3, 3)).copy()
            for name in chans:
                values = motion[:, column]
                column += 1
                axis = _AXIS[name[0]]
                if name.endswith("position"):
                    # Position channels replace the offset on that axis (as Blender's importer reads them).
                    local_t[:, axis] = values * self.scale
                else:
                    # Rotations compose in the declared order: "Z Y X" -> Rz @ Ry @ Rx.
                    local_r = local_r @ _axis_rotation(axis, np.radians(values))
            p = self.parents[j]
            if p < 0:
                positions[:, j] = local_t
                rotations[:, j] = local_r
            else:
                positions[:, j] = positions[:, p] + np.einsum("fij,fj->fi", rotations[:, p], local_t)
                rotations[:, j] = rotations[:, p] @ local_r
        return positions, rotations

    def tail_offsets(self) -> np.ndarray:
        """(J,3) each bone's tail in its joint's local frame, by Blender's import rule (module docstring)."""
        tails = np.zeros((len(self.names), 3))
        for j in range(len(self.names)):
            kids = self.children(j)
            if kids:
                tails[j] = self.offsets[kids].mean(axis=0)
            elif j in self.end_sites:
                tails[j] = self.end_sites[j]
            if np.linalg.norm(tails[j]) <= 0.001 * self.scale:
                tails[j, 1] += 0.1 * self.scale
        return tails

    def bones(self, frames=None) -> tuple[np.ndarray, np.ndarray]:
        """Bone heads and tails (F,J,3) in world space: one bone per joint, head at the joint."""
        positions, rotations = self.forward_kinematics(frames)
        tails = positions + np.einsum("fjab,jb->fja", rotations, self.tail_offsets())
        return positions, tails


def _axis_rotation(axis: int, angles: np.ndarray) -> np.ndarray:
    c, s = np.cos(angles), np.sin(angles)
    r = np.zeros(angles.shape + (3, 3))
    i, k = [a for a in range(3) if a != axis]
    r[..., axis, axis] = 1.0
    r[..., i, i] = c
    r[..., k, k] = c
    # Right-handed rotation about `axis`: (i, k) = (y, z) for x, (z, x) for y, (x, y) for z.
    if axis == 1:
        i, k = k, i
    r[..., i, k] = -s
    r[..., k, i] = s
    return r


def read_bvh(path, scale: float = 1.0) -> BvhClip:
    """Parse a BVH file. Raises ValueError with a one-line reason on malformed input."""
    tokens = Path(path).read_text().split()
    pos = 0

    def take() -> str:
        nonlocal pos
        if pos >= len(tokens):
            raise ValueError(f"{path}: unexpected end of file")
        pos += 1
        return tokens[pos - 1]

    def expect(word: str) -> None:
        got = take()
        if got.lower() != word.lower():
            raise ValueError(f"{path}: expected {word!r}, got {got!r}")

    def vector() -> np.ndarray:
        return np.array([float(take()) for _ in range(3)]) * scale

    names: list[str] = []
    parents: list[int] = []
    offsets: list[np.ndarray] = []
    channels: list[tuple[str, ...]] = []
    end_sites: dict[int, np.ndarray] = {}

    expect("HIERARCHY")
    stack: list[int] = []  # open joints; -2 marks an open End Site
    word = take()
    while True:
        low = word.lower()
        if low in ("root", "joint"):
            name = take()
            if name in names:
                raise ValueError(f"{path}: duplicate joint name {name!r}")
            expect("{")
            expect("OFFSET")
            offset = vector()
            chans: tuple[str, ...] = ()
            if tokens[pos].lower() == "channels":
                take()
                chans = tuple(take().lower() for _ in range(int(take())))
                for c in chans:
                    if c not in ("xposition", "yposition", "zposition", "xrotation", "yrotation", "zrotation"):
                        raise ValueError(f"{path}: unknown channel {c!r} on joint {name!r}")
            parents.append(stack[-1] if stack else -1)
            names.append(name)
            offsets.append(offset)
            channels.append(chans)
            stack.append(len(names) - 1)
        elif low == "end":
            expect("Site")
            expect("{")
            expect("OFFSET")
            end_sites[stack[-1]] = vector()
            stack.append(-2)
        elif low == "}":
            if not stack:
                raise ValueError(f"{path}: unbalanced '}}'")
            stack.pop()
        elif low == "motion":
            break
        else:
            raise ValueError(f"{path}: unexpected token {word!r} in HIERARCHY")
        word = take()
    if stack:
        raise ValueError(f"{path}: HIERARCHY ends with {len(stack)} unclosed block(s)")
    expect("Frames:")
    n_frames = int(take())
    expect("Frame")
    expect("Time:")
    frame_time = float(take())
    n_channels = sum(len(c) for c in channels)
    values = tokens[pos:]
    if len(values) != n_frames * n_channels:
        raise ValueError(f"{path}: MOTION has {len(values)} values, expected {n_frames} x {n_channels}")
    motion = np.array(values, dtype=float).reshape(n_frames, n_channels)
    return BvhClip(
        names=tuple(names),
        parents=np.array(parents, dtype=int),
        offsets=np.array(offsets),
        end_sites=end_sites,
        channels=tuple(channels),
        motion=motion,
        frame_time=frame_time,
        scale=scale,
    )


def read_cmu(filename: str) -> BvhClip:
    """A clip from the mocap folder, in metres."""
    return read_bvh(MOCAP_DIR / filename, scale=CMU_SCALE)


def cut_bvh(source, path, first, last):
    """Write a BVH at ``path`` with ``source``'s header and its frame lines [first, last) (0-based); returns the
    number of frames written."""
    header, motion = Path(source).read_text().split("MOTION", 1)
    lines = motion.strip().splitlines()
    frame_time = next(line for line in lines[:3] if line.lower().startswith("frame time"))
    frames = [line for line in lines if line and (line[0].isdigit() or line[0] in "-.")][first:last]
    Path(path).write_text(f"{header}MOTION\nFrames: {len(frames)}\n{frame_time}\n" + "\n".join(frames) + "\n")
    return len(frames)
