"""One chain solved as a batch of one (the product solves chains in batches: chain/fabrik.solve_chain_batch)."""

import numpy as np

from fullbody_adjust.solver.chain.fabrik import solve_chain_batch


def solve_chain(positions, target, *, parent_direction=None, **kwargs):
    """Solve one chain (n,3) toward ``target`` (3,); joint 0 the fixed base. See ChainResult."""
    parent = None if parent_direction is None else np.asarray(parent_direction, dtype=np.float64)[None]
    return solve_chain_batch(np.asarray(positions, dtype=np.float64)[None], np.asarray(target, dtype=np.float64)[None],
                             parent_directions=parent, **kwargs)[0]
