"""Gaussian measurement noise drawn ahead (pure, no rclpy): the simulated drives'
encoders and the Gough's struts draw a few normals each step, ~1 us a numpy call for
what a slice of a block drawn once gives in ~0.1 us."""

from __future__ import annotations

import numpy as np

__all__ = ["NormalDraws"]

TAKES = 1024         # takes drawn at once


class NormalDraws:
    """N(0, ``std``) draws from the generator ``rng``, ``take(size)`` at a time, drawn
    TAKES takes ahead. The stream is the generator's, in the same order (numpy fills an
    array from it in order), and each value is the one ``rng.normal(0.0, std)`` gives
    (0.0 + std z: tests/common/test_noise.py)."""

    def __init__(self, rng: np.random.Generator, std: float):
        self.rng, self.std = rng, std
        self._block, self._at = np.zeros(0), 0

    def peek(self, size: int) -> np.ndarray:
        """The next ``size`` draws, still to be taken (``take`` gives them again)."""
        if self._at + size > len(self._block):
            self._block, self._at = self.std * self.rng.standard_normal(size * TAKES), 0
        return self._block[self._at:self._at + size]

    def take(self, size: int) -> np.ndarray:
        """The next ``size`` draws."""
        draws = self.peek(size)
        self._at += size
        return draws
