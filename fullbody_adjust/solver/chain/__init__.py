"""One IK group as a chain: FABRIK (Aristidou & Lasenby 2011) with joint limits, for one chain or many at once."""
