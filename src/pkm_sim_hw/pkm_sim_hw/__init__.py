"""Simulated PKM hardware: plant model and simulation node."""
