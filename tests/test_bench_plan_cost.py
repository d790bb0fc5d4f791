"""bench/plan_cost.py's rooms are the cases issue 28 names, as its docstring says."""

import numpy as np
import pytest

from bench.plan_cost import CASES, bodies, room


@pytest.mark.parametrize("n", sorted(CASES))
def test_each_case_has_its_obstacles_and_keeps_every_body_clear_at_the_start_and_the_goal(n):
    for seed in range(3):
        tpl, rad, obs, start, goal = room(n, seed)
        assert tpl.shape == (n, 2) and rad.shape == (n,) and obs.shape == (CASES[n][0], 3)
        assert ((obs[:, 2] >= 0.05) & (obs[:, 2] <= 0.15)).all()
        for pose in (start, goal):
            b = bodies(tpl, pose)
            gap = np.hypot(b[:, None, 0] - obs[None, :, 0], b[:, None, 1] - obs[None, :, 1]) - rad[:, None] - obs[:, 2]
            assert gap.min() >= 0.05
        assert np.allclose(tpl.mean(axis=0), 0.0)
    a, b = room(n, 1), room(n, 1)
    assert all(np.array_equal(np.asarray(x), np.asarray(y)) for x, y in zip(a, b))   # a seed is a room
