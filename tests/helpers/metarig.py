"""The Rigify full human metarig (159 bones) at rest, as the bridge reads it, for solver tests and benches.

tests/data/human_metarig.npz was dumped once from Blender 5.0.1 (`armature_human_metarig_add`, mapped by
bone_mapping.map_rig, read by bridge.pose.read_pose): bone names, parents, world heads/tails, each bone's
pose X axis and the bone map's groups. Loading it needs no Blender.
"""

import json
from pathlib import Path

import numpy as np

from fullbody_adjust.solver.body.model import BodyModel
from fullbody_adjust.solver.obstacles.boxes import Boxes

DATA = Path(__file__).resolve().parents[1] / "data" / "human_metarig.npz"
EFFECTORS = ("hand.L", "hand.R", "foot.L", "foot.R", "head")
PRIORITIES = np.array([2.0, 2.0, 3.0, 3.0, 1.0])  # the extension's defaults: feet 3, hands 2, head 1
CASES = ("near", "far", "obstacle")


def load():
    """(model, heads (J,3), tails (J,3), bone_x_axes (J,3))."""
    with np.load(DATA) as data:
        names = [str(n) for n in data["names"]]
        groups = json.loads(str(data["groups"]))
        model = BodyModel.from_description(names, data["parents"].tolist(), groups)
        return model, data["heads"].astype(np.float64), data["tails"].astype(np.float64), \
            data["bone_x_axes"].astype(np.float64)


def wrists_and_ankles(model, heads):
    """(E,3) current effector positions (NaN for the head: no target)."""
    out = np.full((len(EFFECTORS), 3), np.nan)
    for k, e in enumerate(EFFECTORS[:4]):
        out[k] = heads[model.limbs[{"hand.L": "arm.L", "hand.R": "arm.R", "foot.L": "leg.L",
                                    "foot.R": "leg.R"}[e]].end_bone]
    return out


def left_hand_in_front(model, heads, tails):
    """(targets (5,3) of EFFECTORS, the left arm's rest joints): every effector at its own joint but the left
    hand, in front of the metarig with the elbow bent: 0.65 of the arm's reach from its base, up and forward (the
    metarig faces -Y)."""
    targets = wrists_and_ankles(model, heads)
    joints = model.limbs["arm.L"].joints(heads, tails)
    reach = np.linalg.norm(np.diff(joints, axis=0), axis=1).sum()
    direction = (joints[-1] - joints[0]) / np.linalg.norm(joints[-1] - joints[0]) + np.array([0.0, -0.6, 0.5])
    targets[0] = joints[0] + 0.65 * reach * direction / np.linalg.norm(direction)
    return targets, joints


def case(model, heads, tails, kind):
    """Targets (E,3) and obstacles (Boxes or None) of an Adjust Pose click with the feet planted:
    'near': both hands moved within their arms' reach; 'far': the left hand 3 body heights away (beyond any
    reach), the right one near; 'obstacle': the near targets with a box where the left forearm would go."""
    targets = wrists_and_ankles(model, heads)
    height = float(np.ptp(np.concatenate([heads, tails])[:, 2]))
    targets[0] += np.array([0.04, -0.06, 0.05]) * height
    targets[1] += np.array([-0.03, -0.05, 0.06]) * height
    boxes = None
    if kind == "far":
        targets[0] = heads[model.root] + np.array([3.0, -1.0, 0.5]) * height
    elif kind == "obstacle":
        arm = model.limbs["arm.L"]
        elbow, wrist = heads[arm.bones[-1]], heads[arm.end_bone]
        centre = targets[0] + 0.4 * (elbow - wrist)  # on the forearm of the pose that reaches the target
        half = 0.02 * height
        boxes = Boxes(centre[None] - half, centre[None] + half)
    elif kind != "near":
        raise ValueError(kind)
    return targets, boxes
