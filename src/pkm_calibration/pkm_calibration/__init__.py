"""Kinematic calibration: a machine's real geometry identified from its own measurements."""
