"""Multimodal theta: each mode weighted by its posterior mass (issue 12, item 6)."""

import numpy as np
import pandas as pd
import pytest
from conftest import ROOT, assert_healthy, fit

import stancal
from stancal.numerics.mode_mass import bridge_log_mass, mode_weights

TWO_BRANCH = ROOT / "tests" / "stan" / "two_branch_simulator.stan"


def within_stated_error(weight, low, high, truth):
    """Within 3 standard errors, the se read off the stated 90 % interval
    (the stated intervals held the truth in 92.5 % of 200 seeds of the test below)."""
    return abs(weight - truth) < 3 * (high - low) / (2 * 1.645)


def test_bridge_sampling_recovers_a_known_normalising_constant():
    rng = np.random.default_rng(1)
    scale = np.array([0.5, 2.0, 1.0])
    draws = rng.standard_normal((800, 3)) * scale

    def log_density(u):  # an unnormalised normal: Z = (2 pi)^(3/2) prod(scale)
        return -0.5 * np.sum((u / scale) ** 2, axis=1)

    mass = bridge_log_mass(draws, log_density, rng)
    exact = 1.5 * np.log(2 * np.pi) + np.log(scale).sum()
    assert mass.log_mass_se < 0.05
    assert abs(mass.log_mass - exact) < 3 * mass.log_mass_se


def test_weights_of_two_modes_of_known_mass_from_their_draws():
    """Two normal bumps of equal height, the second twice as wide: it holds
    2/3 of the mass although its mean log density is the same."""
    rng = np.random.default_rng(2)
    narrow, wide = -3 + 0.5 * rng.standard_normal((600, 1)), 3 + 1.0 * rng.standard_normal((600, 1))

    def log_density(u):
        return np.logaddexp(-0.5 * ((u[:, 0] + 3) / 0.5) ** 2, -0.5 * ((u[:, 0] - 3) / 1.0) ** 2)

    masses = [bridge_log_mass(d, log_density, rng) for d in (narrow, wide)]
    weights, low, high = mode_weights(masses, rng)
    assert within_stated_error(weights[1], low[1], high[1], 2 / 3) and high[1] - low[1] < 0.05


@pytest.fixture(scope="module")
def two_mode_fit():
    x = np.linspace(0.5, 2.0, 20)
    y = 1.0 * x + 0.05 * np.random.default_rng(3).standard_normal(x.size)  # g(theta) = 1
    data = stancal.CalibrationData(pd.DataFrame({"x": x, "y": y}), ["x"], "y", {"theta": (-2.0, 2.0)})
    with pytest.warns(stancal.MultimodalWarning, match="weighted by its posterior mass"):
        return fit(data, simulator=TWO_BRANCH, method="koh", discrepancy="none", chains=4, seed=3)


def test_modes_are_weighed_by_posterior_mass_not_by_chains_or_density(two_mode_fit):
    assert_healthy(two_mode_fit)  # R-hat within each mode
    modes = two_mode_fit.modes
    assert len(modes) == 2
    heavy, light = modes
    assert heavy.theta_mean["theta"] == pytest.approx(1.0, abs=0.02)
    assert light.theta_mean["theta"] == pytest.approx(-0.5, abs=0.01)
    # the exact weights are 2/3 and 1/3 (see the simulator); the stated 90 % interval holds them
    assert within_stated_error(heavy.weight, heavy.weight_q05, heavy.weight_q95, 2 / 3)
    assert heavy.weight_q95 - heavy.weight_q05 < 0.1
    # and the light mode's weight against its own exact value, 1/3, at its own stated error
    # (a sum of weights equal to 1 would hold by normalisation alone)
    assert within_stated_error(light.weight, light.weight_q05, light.weight_q95, 1 / 3)
    # both modes fit the data equally well: their mean log densities differ by sampling noise only
    assert abs(heavy.mean_log_density - light.mean_log_density) < 1.0


def test_theta_is_summarised_as_the_weighted_mixture(two_mode_fit):
    assert_healthy(two_mode_fit)
    theta = two_mode_fit.theta_summary()["theta"]
    # 2/3 at 1 and 1/3 at -0.5: mean 0.5, median in the heavy mode, 5 % quantile in the light one
    assert theta["mean"] == pytest.approx(0.5, abs=0.05)
    assert theta["q50"] == pytest.approx(1.0, abs=0.02)
    assert theta["q05"] == pytest.approx(-0.5, abs=0.02)
    assert theta["rhat"] <= 1.01  # within each mode
    table = two_mode_fit.summary()
    assert sorted(table["mode"].unique()) == [1, 2]
    assert table.loc["theta[theta]", "weight"].tolist() == pytest.approx([m.weight for m in two_mode_fit.modes])


class _Optima:
    """A backend whose L-BFGS runs end at given theta optima (one per start, in turn): mode_inits' logic alone."""

    def __init__(self, ends: list[tuple[list[float], float]]):
        self.ends, self.starts = ends, []

    def optima(self, program, data, *, starts, seed):
        self.starts = starts
        # (theta, lp) or (theta, lp, log Laplace mass); without a mass, one that keeps the peaks' order and gaps
        return [({"theta_unit": np.array([[end[0]]])}, end[1], end[2] if len(end) > 2 else end[1])
                for end in (self.ends[i % len(self.ends)] for i in range(len(starts)))]


def test_chains_start_in_every_comparable_mode_and_none_far_below(caplog):
    """Two modes 3 log units apart (comparable: the second holds e^-3 of the
    first's density) each get chains, in turn; a third, 15 below (e^-15 <
    e^-10, MINOR_OPTIMUM_GAP), gets none and is logged; optima within 0.02
    of the box are one mode; a start with no finite density is left out."""
    from stancal.fitting.inits import START_OPTIMA, mode_inits
    from stancal.problem.data import Parameter

    backend = _Optima([([0.50, 0.50], -10.0), ([0.90, 0.10], -13.0), ([0.02, 0.03], -25.0),
                       ([0.51, 0.49], -10.5), ([0.3, 0.3], -np.inf), ([0.90, 0.10], -13.0),
                       ([0.50, 0.51], -10.2), ([0.50, 0.50], -10.0)])
    with caplog.at_level("INFO", logger="stancal"):
        inits, modes = mode_inits(backend, None, {}, chains=4, n_theta=2, seed=1)
    assert len(backend.starts) == START_OPTIMA  # theta spread in strata over the box (spread_theta_inits)
    assert [m.theta_unit for m in modes] == [(0.50, 0.50), (0.90, 0.10), (0.02, 0.03)]
    assert [m.chains for m in modes] == [(0, 2), (1, 3), ()]
    assert [m.below_best for m in modes] == [0.0, 3.0, 15.0]
    assert [m.starts for m in modes] == [4, 2, 1]
    # each chain at the spread start of one of its mode's L-BFGS runs (best first): in the mode's basin, and
    # apart, so that R-hat still compares chains from overdispersed starts (BDA3 section 11.4)
    assert [i["theta_unit"] for i in inits] == [backend.starts[s]["theta_unit"] for s in (0, 1, 7, 5)]
    assert inits[0]["theta_unit"] != inits[2]["theta_unit"]
    assert "(0.020, 0.030) on the unit box (1 of 8 starts) gets no chain" in caplog.text
    assert modes[2].to_dict([Parameter("k", 0.0, 2.0), Parameter("T", 10.0, 20.0)])["theta"] \
        == pytest.approx({"k": 0.04, "T": 10.3})


def test_more_comparable_modes_than_chains_are_warned_of():
    from stancal.fitting.inits import mode_inits
    from stancal.results.modes import MultimodalWarning

    backend = _Optima([([0.2, 0.2], -10.0), ([0.5, 0.5], -10.5), ([0.8, 0.8], -11.0)])
    with pytest.warns(MultimodalWarning, match=r"3 theta modes within 10 log units of the best \(by density or Laplace mass\); 2 chains"):
        _, modes = mode_inits(backend, None, {}, chains=2, n_theta=2, seed=1)
    assert [m.chains for m in modes] == [(0,), (1,), ()]


def test_chains_start_spread_when_no_start_reaches_a_finite_density():
    from stancal.fitting.inits import mode_inits, spread_theta_inits

    inits, modes = mode_inits(_Optima([([0.5, 0.5], -np.inf)]), None, {}, chains=2, n_theta=2, seed=1)
    assert modes == [] and inits == spread_theta_inits(2, 2, np.random.default_rng(1))


def test_laplace_mass_is_exact_for_a_gaussian_and_unknown_at_a_saddle():
    """log ∫ exp(lp) of a Gaussian log density, from a point off its peak
    (L-BFGS stops near, not at, the optimum): log c + d/2 log 2π − ½ log
    det(Σ⁻¹) exactly, whatever the point; NaN at a saddle (no mass to
    approximate) and where the gradient fails."""
    from stancal.numerics.laplace import laplace_log_mass

    precision = np.array([[4.0, 1.0, 0.0], [1.0, 3.0, 0.5], [0.0, 0.5, 0.25]])
    peak, c = np.array([0.3, -1.0, 2.0]), -7.0

    def lp(x):
        return c - 0.5 * (x - peak) @ precision @ (x - peak)

    def gradient(x):
        return -precision @ (x - peak)

    exact = c + 1.5 * np.log(2 * np.pi) - 0.5 * np.log(np.linalg.det(precision))
    for at in (peak, peak + [0.01, -0.02, 0.05]):
        assert laplace_log_mass(lp(at), gradient, at) == pytest.approx(exact, abs=1e-7)
    saddle = np.diag([1.0, -1.0, 1.0])
    assert np.isnan(laplace_log_mass(0.0, lambda x: -saddle @ x, np.zeros(3)))
    assert np.isnan(laplace_log_mass(0.0, lambda x: np.full(3, np.nan), np.zeros(3)))


def test_a_low_but_wide_mode_gets_chains_and_a_low_narrow_one_none(caplog):
    """A mode 15 log units below the best by its peak but within 10 of its
    mass (it is wider: Laplace) may hold comparable mass, so it gets chains;
    one below by both gets none; without masses (NaN, as from cmdstanpy)
    the peaks alone decide, as before."""
    from stancal.fitting.inits import mode_inits
    from stancal.problem.data import Parameter

    ends = [([0.5, 0.5], -10.0, -12.0), ([0.9, 0.1], -25.0, -14.0), ([0.1, 0.9], -25.0, -40.0)]
    with caplog.at_level("INFO", logger="stancal"):
        _, modes = mode_inits(_Optima(ends), None, {}, chains=4, n_theta=2, seed=1)
    assert [m.chains for m in modes] == [(0, 2), (1, 3), ()]
    assert [m.mass_below_best for m in modes] == [0.0, 2.0, 28.0]
    assert "Laplace mass 2.0 below the largest: chains [1, 3]" in caplog.text
    unknown = [(theta, lp, np.nan) for theta, lp, _ in ends]
    _, modes = mode_inits(_Optima(unknown), None, {}, chains=4, n_theta=2, seed=1)
    assert [m.chains for m in modes] == [(0, 1, 2, 3), (), ()]
    assert modes[1].to_dict([Parameter("k", 0.0, 1.0), Parameter("T", 0.0, 1.0)])["log_mass"] is None


def test_a_mode_beyond_the_runs_is_named_and_the_heaviest_one_warned_of():
    """A mode whose theta mean lies beyond the runs the emulator learned
    from (there it extrapolates: the multi-fidelity case's edge mode at
    k = 1.964, beyond the highest expensive run at 1.756) is named in the
    modes' warning and in its summary; when the heaviest mode (or the one
    posterior) lies there, an InputRangeWarning says so; no emulator (None),
    or modes inside the runs, say nothing."""
    from stancal.problem.data import InputRangeWarning
    from stancal.results.modes import Mode, MultimodalWarning, beyond_runs, report

    def mode(k, a, weight):
        return Mode(chains=[0], theta_mean={"k": k, "a": a}, theta_q05={"k": k, "a": a}, theta_q95={"k": k, "a": a},
                    mean_log_density=0.0, weight=weight, weight_q05=weight, weight_q95=weight)

    runs = pd.DataFrame({"k": [0.2, 1.0, 1.756], "a": [0.1, 0.5, 0.9]})
    modes = beyond_runs([mode(1.2, 0.5, 0.998), mode(1.964, 0.05, 0.002)], runs)
    assert modes[0].beyond_runs == [] and modes[0].to_dict()["beyond_runs"] == []
    assert modes[1].beyond_runs == ["k 1.964 above the highest run's 1.756", "a 0.05 below the lowest run's 0.1"]
    with pytest.warns(MultimodalWarning) as caught:
        report(modes)
    assert len(caught) == 1 and ("mode 2 (chains [0], weight 0.002 [0.002, 0.002]): k 1.964 [1.964, 1.964], a 0.05 "
                                 "[0.05, 0.05] (beyond the simulator runs: k 1.964 above the highest run's 1.756, a 0.05 "
                                 "below the lowest run's 0.1; the emulator extrapolates there)") in str(caught[0].message)
    with pytest.warns(InputRangeWarning, match="theta's posterior lies beyond the simulator runs: k 1.964 above"):
        report(beyond_runs([mode(1.964, 0.5, None)], runs))
    assert beyond_runs([mode(1.964, 0.5, None)], None)[0].beyond_runs == []


def test_a_mode_held_by_one_chain_gets_the_r_hat_the_health_check_gives_it():
    """A mode one chain found (the multi-fidelity coverage study's seed 13:
    weight 0.003 at the box's edge) has a split R-hat of its own, which the
    fit's health check takes over the chain's two halves. theta_summary
    reported R-hat over the heavy mode alone (ArviZ gives one chain NaN,
    which max() dropped or kept by the order of the modes): the same R-hat
    in both, whatever the order."""
    import xarray as xr

    from stancal.results.diagnostics import check_sampler
    from stancal.results.modes import Mode
    from stancal.results.summaries import summary_by_mode, theta_summary

    rng = np.random.default_rng(3)
    theta = rng.normal(1.2, 0.05, (4, 400, 1))
    theta[1] = 1.95 + 0.02 * rng.standard_normal((400, 1)) + np.linspace(0, 0.03, 400)[:, None]  # drifts
    posterior = xr.Dataset({"theta": (("chain", "draw", "theta_dim_0"), theta)},
                           coords={"chain": range(4), "draw": range(400), "theta_dim_0": ["k"]})
    stats = xr.Dataset({"energy": (("chain", "draw"), rng.normal(size=(4, 400))),
                        "diverging": (("chain", "draw"), np.zeros((4, 400), bool)),
                        "tree_depth": (("chain", "draw"), np.full((4, 400), 3))})
    mode = {"theta_mean": {}, "theta_q05": {}, "theta_q95": {}, "mean_log_density": 0.0}
    heavy, light = Mode([0, 2, 3], weight=0.997, **mode), Mode([1], weight=0.003, **mode)
    health = check_sampler(posterior, stats, 10, ["theta"], [[0, 2, 3], [1]])
    assert health.max_rhat > 1.01  # the drifting chain's halves disagree
    for modes in ([heavy, light], [light, heavy]):
        assert theta_summary(posterior, modes, ["k"])["k"]["rhat"] == pytest.approx(health.max_rhat)
    table = summary_by_mode(posterior, [heavy, light])  # the summary's block of the one-chain mode too
    assert table.loc["theta[k]", "rhat"].max() == pytest.approx(health.max_rhat)
    # masses unknown: the first mode's summary, a one-chain mode's R-hat over its halves too
    unweighed = Mode([1], **mode), Mode([0, 2, 3], **mode)
    single = check_sampler(posterior.isel(chain=[1]), stats.isel(chain=[1]), 10, ["theta"], None)
    assert theta_summary(posterior, list(unweighed), ["k"])["k"]["rhat"] == pytest.approx(single.max_rhat)
