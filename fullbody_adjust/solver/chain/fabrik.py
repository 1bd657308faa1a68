"""FABRIK on one chain (Aristidou & Lasenby 2011) with the paper's obstacle response (§4.1) and joint limits.

Batch-first: B problems of n joints at once (B, n, 3), e.g. every frame of a clip; one problem is a batch of
one. Each problem stops iterating when it converges (its row leaves the active set), so a problem's result does
not depend on what else is in the batch.

One iteration = a forward pass (effector pinned to the target, joints placed toward the base) then a
backward pass (base pinned, joints placed toward the effector). A solve always ends on a backward pass, which
is where joint limits are enforced: there the parent segment is already final, so the final pose satisfies
the limits exactly. The forward pass applies the limits too, in reverse, only to steer its proposal (as
FABRIK 2011 does in both passes).

Two-segment finish (limited chains, beyond FABRIK): in the backward pass, once joint n-3 is placed, the last
two segments are placed analytically where a swivel position of joint n-2 meets the target with every limit
and obstacle satisfied (chain/finish.py); otherwise the FABRIK step stands. It ends the slow
creep near full stretch, and lets a hinged limb (elbow, knee) turn its bend plane within its twist range.

Obstacles (paper §4.1, boxes): in both passes a joint that lands inside a box, or whose segment crosses one,
is moved (obstacles/response.py). A reachable target must be outside the boxes for a collision-free result; a
target inside a box is a defined result (status 'blocked', reason 'target inside obstacle').

Statuses: 'reached'; 'unreachable' (beyond the reach, or closer to the base than the chain can fold);
'blocked' (penetrations left, target or base inside a box, or an obstacle held the chain); 'limited' (joint
limits held it); 'max_iterations' (iteration cap, or an unconstrained stall).

Modules: chain/settings.py (settings, results, statuses), chain/model.py
(the iteration), obstacles/response.py (obstacle response), chain/finish.py (two-segment finish).
"""

import numpy as np

from .model import ChainModel
from .settings import STATUSES, ChainBatchResult, ChainResult, ChainSettings
from ..errors import SolverInputError
from ..maths.geometry import all_set

__all__ = ["STATUSES", "ChainBatchResult", "ChainResult", "ChainSettings", "solve_chain_batch"]

# ----------------------------------------------------------------------------------------------------------
# Public entry points


def solve_chain_batch(positions, targets, *, settings=ChainSettings(), limits=None, obstacles=None,
                      parent_directions=None):
    """Solve B independent chains of n joints: positions (B,n,3), targets (B,3); limits shared (hinge axes may
    be per problem), obstacles shared (K,3) or per problem (B,K,3), parent_directions (B,3) for joint 0's
    limit. Each problem stops iterating when it converges, so row i equals problem i solved alone."""
    if not isinstance(settings, ChainSettings):
        raise SolverInputError("settings must be a ChainSettings")
    p = _as_chains(positions)
    t = np.asarray(targets, dtype=np.float64)
    if t.shape != (p.shape[0], 3):
        raise SolverInputError(f"targets must have shape ({p.shape[0]},3), got {t.shape}")
    if not all_set(np.isfinite(t)):
        raise SolverInputError("target has NaN/inf")
    model = ChainModel(p, t, settings, limits, obstacles, parent_directions)
    return model.solve(p)


# ----------------------------------------------------------------------------------------------------------
# Input conversion


def _as_chains(positions):
    """``positions`` as floats: a batch of chains (B,n,3) of at least 2 finite joints each."""
    p = np.asarray(positions, dtype=np.float64)
    if p.ndim != 3 or p.shape[-1] != 3:
        raise SolverInputError(f"positions must have shape (B,n,3), got {p.shape}")
    if p.shape[-2] < 2:
        raise SolverInputError("a chain needs at least 2 joints")
    if not all_set(np.isfinite(p)):
        raise SolverInputError("positions have NaN/inf")
    return p

