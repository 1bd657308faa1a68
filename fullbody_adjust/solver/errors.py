"""The one error type the solver raises for bad input."""


class SolverInputError(ValueError):
    """Bad solver input; the message names the problem, e.g. "target has NaN/inf", "segment 2 has zero length"."""
