"""What solves of one body model keep for the solves after them, held by the model (BodyModel.memory): the caller
that holds the model (the bridge keeps one per armature) holds this too, and a new model starts with nothing kept.

Nothing here can be stale: every entry is keyed on all it was computed from (fullbody/prepared.py, limits/human.py), or depends
on the model alone.
"""

from collections import OrderedDict


class SolveMemory:
    """The work a model's solves share (see fullbody/prepared.py for what each holds and how long)."""

    def __init__(self):
        self.starts = OrderedDict()  # prepared start poses (prepared.prepare), least recently used first
        self.limb_records = OrderedDict()  # a limb's default limits, by everything they are computed from
        self.levels = None  # the model's (levels, leaves): the order the top-down pass places bones in
        self.checked_ranges = {}  # validated JointLimits per set of default ranges (human._checked_ranges)
