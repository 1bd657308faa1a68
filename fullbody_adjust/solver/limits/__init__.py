"""Joint limits: the body's default ranges, a rig's own IK limits, and ranges widened to hold a start pose."""
