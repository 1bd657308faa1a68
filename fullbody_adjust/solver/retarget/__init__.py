"""Motion retargeting (paper §6.2.3), the pure part: rigs, rotation transfer, contacts, the plan of every frame's targets, the feet's soles and pivots, measures."""
