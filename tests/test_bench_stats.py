"""bench/vs_cycles.py's statistics of the timed renders: which seeds each budget renders, and the standard error
of the equal-time RMSE ratio from the seeds' scatter."""
import math

import numpy as np

from bench import vs_cycles


def test_timed_seeds_per_scene_and_budget():
    cfg = vs_cycles.FULL
    assert vs_cycles.timed_seeds(cfg, "materials", 5.0) == tuple(range(8))
    assert vs_cycles.timed_seeds(cfg, "materials", 20.0) == tuple(range(5))
    assert vs_cycles.timed_seeds(cfg, "cornell", 5.0) == (vs_cycles.TIMED_SEED,)
    assert vs_cycles.timed_seeds(cfg, "materials", 7.0) == (vs_cycles.TIMED_SEED,)
    for budget in vs_cycles.QUICK.budgets_s:   # the quick run's budgets have seeds of their own
        assert len(vs_cycles.timed_seeds(vs_cycles.QUICK, "materials", budget)) > 1


def test_ratio_standard_error_matches_the_spread_of_repeated_experiments():
    """The delta method's standard error of sqrt(mean(a) / mean(b)) against the spread of the ratio over many
    simulated benchmark runs (heavy-tailed per-seed errors, as the materials scene's fireflies give)."""
    rng = np.random.default_rng(7)
    seeds = 16
    ratios, errors = [], []
    for _ in range(4000):
        a = rng.gamma(4.0, 0.25, seeds) * 0.64   # mean 0.64
        b = rng.gamma(4.0, 0.25, seeds)           # mean 1.0
        r = math.sqrt(a.mean() / b.mean())
        ratios.append(r)
        errors.append(vs_cycles.ratio_standard_error(r, list(a), list(b)))
    spread = np.std(ratios)
    # Over 4000 runs the spread itself is known to about 1.1%, the mean of the estimates to better.
    assert abs(np.mean(errors) / spread - 1.0) < 0.08, (np.mean(errors), spread)
    assert abs(np.mean(ratios) - 0.8) < 0.01


def test_ratio_standard_error_needs_two_seeds():
    assert vs_cycles.ratio_standard_error(0.8, [1.0], [2.0]) is None
    assert vs_cycles.ratio_standard_error(1.0, [1.0, 1.0], [1.0, 1.0]) == 0.0
