"""A cheap simulator with its own calibration parameter theta_l (Goh et al.
2013, Technometrics 55(4)): the calibrated simulator is
rho f_low(x, theta_l) + g(x, theta). The co-kriging of
stancal.numerics.multifidelity_theta against the formulas written out
with one kernel per level; modular.stan's (theta, theta_l) posterior
against quadrature of the same model; and the refusals before any compile."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pandas as pd
import pytest
from conftest import assert_healthy, fit
from scipy import linalg, stats
from scipy.stats import qmc

import stancal
from stancal.fitting.stage_one import fidelity_levels
from stancal.numerics import multifidelity as mf
from stancal.numerics.multifidelity_theta import cheap_points, expensive_points, with_inactive
from stancal.numerics.scalable_emulator import Hyperparameters, run_nugget_variance
from stancal.numerics.vector_emulator import same_point
from stancal.problem.config import ConfigError, load_config
from stancal.problem.data import DataError

A_BOUNDS, K_BOUNDS = (0.5, 2.0), (0.0, 1.0)
A_TRUE, K_TRUE, RHO_TRUE = 0.8, 0.6, 1.1


def cheap(t: np.ndarray, a: np.ndarray) -> np.ndarray:
    """The cheap simulator: Newton cooling at its own rate a."""
    return np.exp(-a * t)


def expensive(t: np.ndarray, k: np.ndarray) -> np.ndarray:
    """The expensive one: the cheap one at its best rate a = 0.8, scaled, plus a term in k alone. (With
    a term in t too, 0.3 k t, the GP of the shortfall absorbs a wrong rate and stage 1's profile in a is
    flat, 9.18 to 10.2 over [0.5, 2]: theta_l is then weakly identified, as KOH's theta is with a
    flexible discrepancy. Here the profile has its minimum at 0.80, 3.9 below its neighbours at 0.65
    and 0.95.)"""
    return RHO_TRUE * cheap(t, A_TRUE) + 0.3 * k


def lhs(n: int, seed: int, bounds: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
    u = qmc.LatinHypercube(d=2, seed=seed).random(n)
    return 2 * u[:, 0], bounds[0] + np.ptp(bounds) * u[:, 1]


def problem(seed: int = 0, low: int = 30, high: int = 8) -> stancal.CalibrationData:
    rng = np.random.default_rng(seed)
    t_low, a = lhs(low, seed + 1, A_BOUNDS)
    t_high, k = lhs(high, seed + 2, K_BOUNDS)
    t = np.linspace(0.2, 1.8, 12)
    physical = pd.DataFrame({"t": t, "excess": expensive(t, K_TRUE) + rng.normal(0, 0.01, len(t))})
    return stancal.CalibrationData(
        physical, ["t"], "excess", {"k": K_BOUNDS}, theta_low={"a": A_BOUNDS},
        runs=[pd.DataFrame({"t": t_low, "a": a, "excess": cheap(t_low, a)}),
              pd.DataFrame({"t": t_high, "k": k, "excess": expensive(t_high, k)})])


def direct_cokriging(x_low, a_low, y_low, x_high, k_high, y_high, h1, h2, rho, a, points):
    """Kennedy & O'Hagan (2000)'s co-kriging written out: k_1 over (x, a),
    k_2 over (x, k); the expensive runs' and the points' cheap part at a."""
    def k1(xa, xb):
        return h1.sd**2 * mf.se_correlation(xa, xb, h1.length_scale)

    def k2(xa, xb):
        return h2.sd**2 * mf.se_correlation(xa, xb, h2.length_scale)

    low = np.hstack([x_low, a_low])
    high_cheap = np.hstack([x_high, np.full((len(x_high), 1), a)])
    high_own = np.hstack([x_high, k_high])
    K = np.block([[k1(low, low), rho * k1(low, high_cheap)],
                  [rho * k1(high_cheap, low), rho**2 * k1(high_cheap, high_cheap) + k2(high_own, high_own)]])
    K[np.diag_indices_from(K)] += np.r_[np.full(len(low), run_nugget_variance(h1)),
                                         np.full(len(x_high), run_nugget_variance(h2))]
    y = np.r_[y_low - h1.mean, y_high - rho * h1.mean - h2.mean]
    p_cheap = np.hstack([points[:, :1], np.full((len(points), 1), a)])
    p_own = points[:, :2]
    cross = np.hstack([rho * k1(p_cheap, low), rho**2 * k1(p_cheap, high_cheap) + k2(p_own, high_own)])
    factor = linalg.cho_factor(K, lower=True)
    mean = rho * h1.mean + h2.mean + cross @ linalg.cho_solve(factor, y)
    cov = rho**2 * k1(p_cheap, p_cheap) + k2(p_own, p_own) - cross @ linalg.cho_solve(factor, cross.T)
    return mean, np.diag(cov)


def test_the_cokriging_with_a_cheap_theta_matches_the_formulas_written_out():
    rng = np.random.default_rng(3)
    x_low, a_low, x_high, k_high = rng.uniform(size=(20, 1)), rng.uniform(size=(20, 1)), \
        rng.uniform(size=(6, 1)), rng.uniform(size=(6, 1))
    y_low, y_high = np.sin(3 * x_low[:, 0] + a_low[:, 0]), np.cos(2 * x_high[:, 0]) + k_high[:, 0]
    h1 = Hyperparameters(0.1, 0.9, np.array([0.3, 0.4]), 1e-3)
    h2 = Hyperparameters(-0.2, 0.5, np.array([0.5, 0.6]), 2e-3)
    rho, a = 1.3, 0.35
    levels = [mf.Level(with_inactive(h1, 1, 0, 1), 1.0, cheap_points(x_low, a_low, 1), y_low),
              mf.Level(with_inactive(h2, 0, 1, 2), rho, expensive_points(x_high, k_high, np.array([a])), y_high)]
    points = np.hstack([rng.uniform(size=(7, 2)), np.full((7, 1), a)])
    mean, variance = mf.predict(levels, points)
    want_mean, want_variance = direct_cokriging(x_low, a_low, y_low, x_high, k_high, y_high, h1, h2, rho, a, points)
    np.testing.assert_allclose(mean, want_mean, rtol=1e-9, atol=1e-10)
    np.testing.assert_allclose(variance, want_variance, rtol=1e-7, atol=1e-10)
    assert np.ptp(variance) > 1e-3  # the points differ: a check that cannot pass on constants


def quadrature_posterior(data: stancal.CalibrationData, levels: list[mf.Level]) -> dict[str, np.ndarray]:
    """(theta, theta_l)'s posterior quantiles (5, 50, 95 %) under modular.stan's
    model with no discrepancy: p(y | y_sim, theta, theta_l) (the runs' own
    density left out, as modular.stan does), y ~ N(m, V + nugget^2 S +
    noise_sd^2 I), m and V the co-kriging at
    (x, theta, theta_l) with the expensive runs' cheap part at theta_l;
    uniform priors, noise_sd half-normal(0, 1); on a grid."""
    x = data.scaling.to_unit(data.physical, data.inputs)
    y = data.scaling.standardise(data.physical[data.output].to_numpy())
    grid, noise = np.linspace(0, 1, GRID), np.linspace(0.001, 0.2, 300)
    log_post = np.empty((len(grid), len(grid), len(noise)))
    top = levels[1]
    misfit = top.hyperparameters.nugget**2 * same_point(x)  # the emulator's nugget at the points (modular.stan)
    for j, a in enumerate(grid):
        at = [levels[0], replace(top, xt=np.hstack([top.xt[:, :-1], np.full((len(top.xt), 1), a)]))]
        for i, k in enumerate(grid):
            mean, cov = mf.predictive(at, np.hstack([x, np.full((len(x), 1), k), np.full((len(x), 1), a)]))
            cov = cov + misfit
            values, vectors = np.linalg.eigh(cov)
            projected = vectors.T @ (y - mean)
            variance = np.maximum(values, 0)[:, None] + noise[None, :] ** 2
            log_post[i, j] = (-0.5 * (projected[:, None] ** 2 / variance).sum(0) - 0.5 * np.log(variance).sum(0)
                              + stats.halfnorm.logpdf(noise))
    w = np.exp(log_post - log_post.max()).sum(axis=2)
    w /= w.sum()
    out = {}
    for name, bounds, marginal in (("k", K_BOUNDS, w.sum(1)), ("a", A_BOUNDS, w.sum(0))):
        values = bounds[0] + np.ptp(bounds) * grid
        out[name] = np.interp([0.05, 0.5, 0.95], np.cumsum(marginal) - marginal / 2, values)
    return out


GRID = 61  # grid step 1/60 of each range: 0.017 in k, 0.025 in a


@pytest.fixture(scope="module")
def theta_low_fit():
    return fit(problem(), method="modular", discrepancy="none", draws=600)


@pytest.mark.slow  # one fit with stage 1, about 35 s: the default run's time stays as it was
def test_the_fit_recovers_theta_and_the_cheap_theta_as_quadrature_does(theta_low_fit):
    assert_healthy(theta_low_fit)
    posterior = theta_low_fit.idata["posterior"]
    levels = fidelity_levels(theta_low_fit.data, theta_low_fit.emulator["hyperparameters"]["levels"])
    want = quadrature_posterior(theta_low_fit.data, levels)
    tolerance = {"k": 0.01, "a": 0.06}  # a grid step plus the 5 and 95 % quantiles' Monte Carlo error
    for name, draws, truth in (("k", posterior["theta"].sel(theta_name="k"), K_TRUE),
                               ("a", posterior["theta_low"].sel(theta_low_name="a"), A_TRUE)):
        quantiles = np.quantile(np.asarray(draws).ravel(), [0.05, 0.5, 0.95])
        assert quantiles[0] < truth < quantiles[2], (name, quantiles)
        np.testing.assert_allclose(quantiles, want[name], atol=tolerance[name], err_msg=name)
    # stage 1's estimate of the cheap simulator's best rate, and rho (the expensive runs are
    # 1.1 cheap(t, 0.8) + a term in k alone)
    assert abs(theta_low_fit.emulator["theta_low_stage1"]["a"] - A_TRUE) < 0.05
    assert abs(theta_low_fit.emulator["level_rho"][0] - RHO_TRUE) < 0.1
    rows = theta_low_fit.summary().index
    assert "theta_low[a]" in rows and "theta[k]" in rows


@pytest.mark.parametrize(("change", "message"), [
    ({"theta_low": {"k": (0.0, 1.0)}}, "low-fidelity theta 'k' is also a theta"),
    ({"theta_low": {"t": (0.0, 1.0)}}, "low-fidelity theta 't' is also a data column"),
    ({"low_k_column": True}, "column 'k' is a theta"),
    ({"no_low": True}, "exactly one level of low-fidelity runs"),
    ({"drop_a": True}, "'a'"),
])
def test_a_bad_cheap_theta_is_refused_naming_it(change, message):
    data = problem(low=10, high=4)
    low, high = data.runs_by_fidelity()
    if change.get("low_k_column"):
        low = low.assign(k=0.5)
    if change.get("drop_a"):
        low = low.drop(columns="a")
    runs = [high] if change.get("no_low") else [low, high]
    with pytest.raises(DataError, match=message):
        stancal.CalibrationData(data.source, ["t"], "excess", {"k": K_BOUNDS},
                                theta_low=change.get("theta_low", {"a": A_BOUNDS}), runs=runs)


def test_a_config_declares_the_cheap_theta_and_it_round_trips(tmp_path):
    data = problem(low=10, high=4)
    data.source.to_csv(tmp_path / "physical.csv", index=False)
    data.runs_by_fidelity()[0].to_csv(tmp_path / "low.csv", index=False)
    data.runs.to_csv(tmp_path / "high.csv", index=False)
    config = ('[physical]\ncsv = "physical.csv"\ninputs = ["t"]\noutput = "excess"\n'
              '[simulator]\nruns = "high.csv"\n[simulator.theta]\nk = [0.0, 1.0]\n'
              '[simulator.low_fidelity]\nruns = "low.csv"\n[simulator.low_fidelity.theta]\n{}\n')
    (tmp_path / "config.toml").write_text(config.format("a = [0.5, 2.0]"))
    loaded = load_config(tmp_path / "config.toml").data
    assert loaded.theta_low_names == ["a"]
    assert stancal.CalibrationData.from_dict(loaded.to_dict()).theta_low_names == ["a"]
    (tmp_path / "config.toml").write_text(config.format("a = 0.5"))
    with pytest.raises(ConfigError, match=r"\[simulator.low_fidelity.theta\] a"):
        load_config(tmp_path / "config.toml")
    (tmp_path / "config.toml").write_text(config.format("k = [0.0, 1.0]"))
    with pytest.raises(DataError, match="low-fidelity theta 'k' is also a theta"):
        load_config(tmp_path / "config.toml")


@pytest.mark.slow  # one fit with stage 1, about 35 s: the default run's time stays as it was
def test_the_cheap_theta_is_reported_beside_theta_and_survives_saving(theta_low_fit, tmp_path):
    """summary.json, the report's parameter table and the theta figure carry
    theta_l beside theta; a saved fit loads with it and predicts."""
    from stancal.reporting.plots import plot_theta

    summary = theta_low_fit.to_summary_json()
    assert summary["theta_low"]["a"]["q05"] < A_TRUE < summary["theta_low"]["a"]["q95"]
    assert abs(summary["emulator"]["theta_low_stage1"]["a"] - A_TRUE) < 0.05
    figure = plot_theta(theta_low_fit)
    assert [ax.get_xlabel() for ax in figure.axes] == ["k", "a"]
    stancal.write_calibration(theta_low_fit, tmp_path)
    assert "| a | " in (tmp_path / "report.md").read_text()
    again = stancal.CalibrationResult.load(theta_low_fit.save(tmp_path / "fit.nc"))
    assert again.data.theta_low_names == ["a"]
    predicted = again.predict(pd.DataFrame({"t": [0.5, 1.5]}))
    truth = expensive(np.array([0.5, 1.5]), K_TRUE)
    assert np.all(np.abs(predicted["zeta_q50"].to_numpy() - truth) < 0.05), predicted


@pytest.mark.slow  # reuses the fit above
def test_the_emulators_mean_as_a_function_of_theta_takes_stage_ones_cheap_theta(theta_low_fit):
    """The confounding check and the L2 projection call the emulator's mean
    at (x, theta) alone: with a cheap level's own theta_l it sits at stage
    1's value (review of issue 34: a shape error before)."""
    from stancal.fitting.stage_one import emulator_mean_function

    data = theta_low_fit.data
    at = emulator_mean_function(data, theta_low_fit.emulator["hyperparameters"], 1)
    values = at(data.physical, np.array([[0.3], [0.7]]))
    assert values.shape == (2, len(data.physical)) and np.all(np.isfinite(values))
    assert not np.allclose(values[0], values[1])  # theta moves the mean
