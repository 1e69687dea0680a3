"""Noise drawn ahead (pkm_common.noise): the generator's own values, in its order."""

import numpy as np

from pkm_common.noise import TAKES, NormalDraws


def test_the_draws_are_the_ones_normal_gives_one_take_at_a_time():
    std, size = 2.5e-7, 6
    draws = NormalDraws(np.random.default_rng(5), std)
    reference = np.random.default_rng(5)
    takes = 2 * TAKES + 3                        # across two new blocks
    got = np.concatenate([draws.take(size) for _ in range(takes)])
    want = np.concatenate([reference.normal(0.0, std, size) for _ in range(takes)])
    assert got.view(np.int64).tolist() == want.view(np.int64).tolist()      # bit for bit
    assert abs(got.std() / std - 1.0) < 0.05
