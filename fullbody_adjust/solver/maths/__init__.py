"""Numbers and vectors the solver computes with: one frame or many (lanes, vectors), vector and matrix helpers, rotation channels."""
