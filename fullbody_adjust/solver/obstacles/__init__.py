"""Obstacles (paper §4.1): boxes, the collision tests, the two-sphere response inside FABRIK, and limbs kept clear by their thickness."""
