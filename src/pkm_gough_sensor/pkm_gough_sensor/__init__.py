"""Gough platform metrology model and sensor node."""
