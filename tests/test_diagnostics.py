"""Sampler checks and mode detection on constructed draws."""

import numpy as np
import pytest
import xarray as xr

from stancal.fitting.inits import spread_theta_inits
from stancal.results.diagnostics import check_sampler
from stancal.results.modes import find_modes

rng = np.random.default_rng(0)


def stats(chains=4, draws=500, divergent=0, depth=3):
    diverging = np.zeros((chains, draws), bool)
    diverging.flat[:divergent] = True
    return xr.Dataset({
        "diverging": (("chain", "draw"), diverging),
        "tree_depth": (("chain", "draw"), np.full((chains, draws), depth)),
        "energy": (("chain", "draw"), rng.standard_normal((chains, draws))),
    })


def posterior(theta):
    return xr.Dataset({"theta": (("chain", "draw", "theta_name"), theta)},
                      coords={"theta_name": ["k"]})


def test_clean_draws_pass():
    d = check_sampler(posterior(rng.standard_normal((4, 500, 1))), stats(), 10, ["theta"])
    assert d.ok, d.messages


def test_divergences_are_counted_and_explained():
    d = check_sampler(posterior(rng.standard_normal((4, 500, 1))), stats(divergent=7), 10, ["theta"])
    assert d.divergences == 7
    assert any("7 of 2000 transitions diverged" in m and "adapt_delta" in m for m in d.messages)


def test_disagreeing_chains_raise_rhat():
    theta = rng.standard_normal((4, 500, 1))
    theta[2:] += 3
    d = check_sampler(posterior(theta), stats(), 10, ["theta"])
    assert d.max_rhat > 1.5
    assert any("R-hat up to" in m for m in d.messages)


def test_rhat_is_taken_within_each_theta_mode():
    theta = rng.standard_normal((4, 500, 1))
    theta[2:] += 3  # chains 2 and 3 sit in another mode
    d = check_sampler(posterior(theta), stats(), 10, ["theta"], modes=[[0, 1], [2, 3]])
    assert d.max_rhat < 1.01 and d.ok, d.messages
    stuck = theta.copy()
    stuck[3] = np.linspace(2, 4, 500)[:, None]  # a chain that drifts inside its mode
    d = check_sampler(posterior(stuck), stats(), 10, ["theta"], modes=[[0, 1], [2, 3]])
    assert any("chains within a theta mode disagree" in m for m in d.messages)
    lone = theta.copy()
    lone[3] = np.linspace(5, 7, 500)[:, None]  # a mode of one chain is split in halves
    d = check_sampler(posterior(lone), stats(), 10, ["theta"], modes=[[0, 1], [2], [3]])
    assert d.max_rhat > 1.5


def test_low_ess_is_reported():
    walk = rng.standard_normal((4, 500, 1)).cumsum(axis=1) * 0.05
    d = check_sampler(posterior(walk), stats(), 10, ["theta"])
    assert any("effective sample size" in m for m in d.messages)


def test_tree_depth_hits():
    d = check_sampler(posterior(rng.standard_normal((4, 500, 1))), stats(depth=10), 10, ["theta"])
    assert d.treedepth_hits == 2000


def test_two_modes_are_found_and_ordered_by_density():
    theta = np.concatenate([0.1 + 0.01 * rng.standard_normal((2, 300, 1)),
                            0.6 + 0.01 * rng.standard_normal((2, 300, 1))])
    lp = np.concatenate([np.full((2, 300), -50.0), np.full((2, 300), -40.0)])
    modes = find_modes(theta, lp, ["k"], np.array([1.0]))
    assert [m.chains for m in modes] == [[2, 3], [0, 1]]
    assert modes[0].theta_mean["k"] == pytest.approx(0.6, abs=0.01)


def test_one_mode_when_chains_overlap():
    modes = find_modes(0.5 + 0.05 * rng.standard_normal((4, 300, 1)), np.zeros((4, 300)),
                       ["k"], np.array([1.0]))
    assert len(modes) == 1 and modes[0].chains == [0, 1, 2, 3]


def test_inits_stratify_every_theta():
    inits = spread_theta_inits(4, 2, np.random.default_rng(1))
    unit = np.array([i["theta_unit"] for i in inits])
    for j in range(2):
        strata = np.floor((unit[:, j] - 0.03) / 0.94 * 4).astype(int)
        assert sorted(strata) == [0, 1, 2, 3]
