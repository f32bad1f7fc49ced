"""The scalable path (issue: thousands of points and runs): the
Hilbert-space discrepancy, the precomputed-weight emulator, the automatic
switch, and agreement with the exact programs on problems both can fit."""

from __future__ import annotations

import re
import warnings

import numpy as np
import pandas as pd
import pytest
from conftest import ROOT, assert_healthy, assert_healthy_summary, case_study_module, fit, no_stancal_warnings
from scipy import optimize

import stancal
from stancal.fitting.plan import plan_scalar
from stancal.numerics import hsgp
from stancal.numerics import scalable_emulator as scalable
from stancal.numerics.kernels import ard_cross_cov
from stancal.problem.options import EXACT_SIZE_LIMIT, ModelOptions
from stancal.stan.backends import get_backend
from stancal.stan.standata import build_emulator_data, emulator_run_data, to_stan_json

SENSOR = ROOT / "case_studies" / "sensor_log"
sensor_physics = case_study_module(SENSOR)  # the case study's own physics
newton = sensor_physics.newton

THETA = {"k": (0.01, 0.1), "Ta": (15.0, 25.0)}


def sensor_data(n: int, runs: int, seed: int, discrepancy: float = 0.0) -> stancal.CalibrationData:
    """n readings of the sensor-log physics at k = 0.045, Ta = 21.3 (noise sd
    0.3), plus a smooth discrepancy of the given amplitude; the first
    ``runs`` of the shipped runs."""
    rng = np.random.default_rng(seed)
    t, T0 = rng.uniform(0, 60, n), rng.uniform(55, 95, n)
    gap = discrepancy * np.sin(np.pi * t / 40) * (T0 - 55) / 40
    physical = pd.DataFrame({"t": t, "T0": T0,
                             "temperature": newton(t, T0, 0.045, 21.3) + gap + 0.3 * rng.standard_normal(n)})
    shipped = pd.read_csv(SENSOR / "runs.csv").iloc[:runs]
    # t is drawn over [0, 60], a little wider than the first runs' t: the inputs outside the runs'
    # range, found here in numpy, must be named by an InputRangeWarning, and no other column
    outside = {c for c in ("t", "T0")
               if ((physical[c] < shipped[c].min()) | (physical[c] > shipped[c].max())).any()}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", stancal.InputRangeWarning)
        data = stancal.CalibrationData(physical, ["t", "T0"], "temperature", THETA, runs=shipped)
    named = {re.match(r"physical input '(\w+)' lies outside", str(w.message))[1]
             for w in caught if issubclass(w.category, stancal.InputRangeWarning)}
    for w in caught:
        if not issubclass(w.category, stancal.InputRangeWarning):
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    assert named == outside, (named, outside)
    return data


# ---- the Hilbert-space basis (numpy mirror of functions/hsgp.stan) ----------

@pytest.mark.parametrize("kernel", ["se", "matern52"])
@pytest.mark.parametrize("dims", [1, 2])
def test_hilbert_space_covariance_matches_the_kernel(kernel, dims):
    """Riutort-Mayol et al.'s approximation of the covariance, within 2 % of
    the kernel's variance at the shortest length scale the first basis is
    built for and far closer at the typical one."""
    names = ["t", "T0"][:dims]
    basis = hsgp.first_basis(kernel, names)
    x = np.random.default_rng(1).uniform(0, 1, (150, dims))
    phi = hsgp.basis(x, basis.index, basis.boundary)
    for length_scale, tolerance in ((hsgp.SHORTEST_EXPECTED, 0.02), (hsgp.TYPICAL_EXPECTED, 2e-3)):
        ell = np.full(dims, length_scale)
        sd = hsgp.weight_sd(basis.index, basis.boundary, kernel, 1.7, ell)
        exact = ard_cross_cov(x, x, 1 if kernel == "se" else 2, 1.7, ell)
        assert np.abs((phi * sd**2) @ phi.T - exact).max() / 1.7**2 < tolerance


def test_the_basis_check_flags_length_scales_it_cannot_represent():
    basis = hsgp.first_basis("se", ["t", "T0"])
    short, long = basis.shortest_length_scale("se"), basis.longest_length_scale("se")
    rng = np.random.default_rng(0)
    assert hsgp.basis_problems(basis, "se", rng.normal((short + long) / 2, 0.005, (400, 2)), ["t", "T0"]) == []
    problems = hsgp.basis_problems(basis, "se", rng.normal([0.5 * short[0], 1.3 * long[1]], 0.005, (400, 2)),
                                   ["t", "T0"])
    assert len(problems) == 2
    assert "over t" in problems[0] and "shorter" in problems[0]
    assert "over T0" in problems[1] and "pressed against" in problems[1]
    draws = np.random.default_rng(0).normal([0.5 * short[0], 1.3 * long[1]], 0.01, (400, 2))
    refined = hsgp.refined_basis("se", basis, draws, ["t", "T0"])
    assert refined.shortest_length_scale("se")[0] <= np.quantile(draws[:, 0], 0.05)
    assert refined.longest_length_scale("se")[1] >= 2 * long[1] - 1e-9


def test_a_length_scale_the_data_say_nothing_about_is_not_pressed():
    """Draws from the prior itself put half their mass beyond the first
    basis's cap: that is no reason to refit with a basis five times larger;
    draws the data push beyond it are."""
    basis = hsgp.first_basis("se", ["t", "T0"])
    long = basis.longest_length_scale("se")
    rng = np.random.default_rng(1)
    prior_draws = hsgp.LENGTH_SCALE_PRIOR.rvs(size=(4000, 2), random_state=rng)
    assert not hsgp.pressed(prior_draws, long).any()
    assert hsgp.basis_problems(basis, "se", prior_draws, ["t", "T0"]) == []
    pushed = prior_draws * 2.5  # the likelihood favours long length scales
    assert hsgp.pressed(pushed, long).all()
    refined = hsgp.refined_basis("se", basis, pushed, ["t", "T0"])
    np.testing.assert_allclose(refined.longest_length_scale("se"), 2 * long)


def test_a_product_basis_too_large_is_refused_with_another_route():
    with pytest.raises(hsgp.BasisTooLargeError, match="fewer inputs.*approximation = 'exact'"):
        hsgp.first_basis("matern52", ["a", "b", "c"])


# ---- the switch ----------------------------------------------------------

def test_auto_switches_above_the_limit_and_says_so(caplog):
    big = sensor_data(EXACT_SIZE_LIMIT + 1, 50, seed=1)
    small = sensor_data(200, 50, seed=1)
    simulator = SENSOR / "simulator.stan"
    with caplog.at_level("INFO", logger="stancal"):
        assert plan_scalar(big, simulator, None).name == "koh_hsgp"
    assert sum("koh_hsgp runs" in r.message for r in caplog.records) == 1
    assert plan_scalar(small, simulator, None).name == "koh"
    assert plan_scalar(small, simulator, None, ModelOptions(approximation="hsgp")).name == "koh_hsgp"
    assert plan_scalar(big, simulator, None, ModelOptions(approximation="exact")).name == "koh"
    assert plan_scalar(big, None, "modular").name == "modular_hsgp"
    assert plan_scalar(big, None, "koh_emulator").name == "modular_hsgp"


def test_what_the_scalable_path_cannot_do_is_an_error_that_says_why():
    data = sensor_data(100, 50, seed=1)
    with pytest.raises(ValueError, match="orthogonal.*approximation = 'exact'"):
        plan_scalar(data, SENSOR / "simulator.stan", "koh",
                      ModelOptions(discrepancy="orthogonal", approximation="hsgp"))
    physical = data.physical.assign(humidity=np.linspace(30, 70, 100))
    with_covariate = stancal.CalibrationData(physical, ["t", "T0"], "temperature", THETA,
                                             covariates=["humidity"])
    with pytest.raises(ValueError, match="covariates"):
        plan_scalar(with_covariate, SENSOR / "simulator.stan", "koh", ModelOptions(approximation="hsgp"))


# ---- the scalable emulator ---------------------------------------------------

def test_stage_one_gradient_is_the_objectives():
    data = sensor_data(10, 200, seed=2)
    runs = emulator_run_data(data)
    xt, y = np.column_stack([runs["x_sim"], runs["theta_sim"]]), np.asarray(runs["y_sim"])
    u = np.array([0.1, np.log(0.8), *np.log([0.4, 0.9, 0.5, 1.5]), np.log(0.03)])
    value = lambda v: scalable.negative_log_posterior(v, xt, y)[0]  # noqa: E731
    gradient = lambda v: scalable.negative_log_posterior(v, xt, y)[1]  # noqa: E731
    assert optimize.check_grad(value, gradient, u) < 1e-4 * np.abs(gradient(u)).max()


def test_stage_one_mode_is_the_stan_optimisers():
    """scipy on the numpy objective and L-BFGS through Stan's own log density
    of emulator.stan (the exact path's stage 1) find the same mode."""
    data = sensor_data(10, 120, seed=3)
    runs = emulator_run_data(data)
    xt = np.column_stack([runs["x_sim"], runs["theta_sim"]])
    mine, used = scalable.fit_hyperparameters(xt, np.asarray(runs["y_sim"]), seed=1)
    assert used == 120
    program = plan_scalar(data, None, "modular").stan_programs()[0]  # emulator.stan
    stan_mode, _ = get_backend("pystan").posterior_mode(
        program, to_stan_json(build_emulator_data(data, ModelOptions())), starts=4, seed=1)
    np.testing.assert_allclose(mine.length_scale, stan_mode["emulator_length_scale"].ravel(), rtol=0.02)
    np.testing.assert_allclose(mine.sd, stan_mode["emulator_sd"].ravel()[0], rtol=0.02)
    np.testing.assert_allclose(mine.mean, stan_mode["emulator_mean"].ravel()[0], atol=0.02)


def test_emulator_mean_and_variance_against_the_full_gp():
    """The Chebyshev interpolant is within MEAN_TOLERANCE of the exact GP mean
    of all runs at new theta, and the local GP's variance is at least the
    full GP's (it conditions on fewer runs) and within a small factor of it."""
    data = sensor_data(300, 800, seed=4)
    runs = emulator_run_data(data)
    x_runs, theta_runs, y = runs["x_sim"], runs["theta_sim"], np.asarray(runs["y_sim"])
    x = data.scaling.to_unit(data.physical, data.inputs)
    emulator, info = scalable.ScalableEmulator.fit(x_runs, theta_runs, y, x, seed=1)
    assert info["theta_interpolation_error"] <= scalable.MEAN_TOLERANCE
    h = emulator.hyperparameters
    xt = np.column_stack([x_runs, theta_runs])
    K = scalable.run_covariance(xt, h)
    theta = np.random.default_rng(0).uniform(0.1, 0.9, 2)
    cross = h.sd**2 * scalable.se_correlation(np.column_stack([x, np.tile(theta, (len(x), 1))]), xt, h.length_scale)
    exact_mean = h.mean + cross @ np.linalg.solve(K, y - h.mean)
    interpolated = h.mean + emulator.mean_weights(x) @ scalable.chebyshev_basis(theta[None, :], emulator.interpolant.degrees)[0]
    assert np.abs(interpolated - exact_mean).max() <= 2 * scalable.MEAN_TOLERANCE
    exact_variance = h.sd**2 - np.einsum("ij,ji->i", cross, np.linalg.solve(K, cross.T))
    local = emulator.variance(x, theta)
    assert np.all(local >= exact_variance - 1e-9)
    assert np.sqrt(local).mean() <= 3 * np.sqrt(np.maximum(exact_variance, 0)).mean()


def test_emulator_error_basis_against_the_full_gp_covariance():
    """With few runs the emulator's error is correlated across the points;
    its basis (Nystroem through LANDMARKS of 1,000 points, then an SVD)
    reproduces the exact predictive covariance at theta to within 2 % of its
    largest eigenvalue, and what it leaves of each point's variance is at
    least what the exact GP leaves."""
    data = sensor_data(1000, 100, seed=4)
    runs = emulator_run_data(data)
    x_runs, theta_runs, y = runs["x_sim"], runs["theta_sim"], np.asarray(runs["y_sim"])
    x = data.scaling.to_unit(data.physical, data.inputs)
    emulator, _ = scalable.ScalableEmulator.fit(x_runs, theta_runs, y, x, seed=1)
    h = emulator.hyperparameters
    theta = np.array([0.4, 0.6])
    points = np.column_stack([x, np.tile(theta, (len(x), 1))])
    cross = h.sd**2 * scalable.se_correlation(points, emulator.xt_runs, h.length_scale)
    exact = h.sd**2 * scalable.se_correlation(points, points, h.length_scale) - cross @ np.linalg.solve(
        scalable.run_covariance(emulator.xt_runs, h), cross.T)
    largest = np.linalg.eigvalsh(exact)[-1]
    basis = emulator.error_basis(x, theta, threshold=1e-6 * largest)
    assert 0 < basis.columns.shape[1] <= scalable.MAX_ERROR_RANK
    assert np.linalg.norm(exact - basis.columns @ basis.columns.T, 2) <= 0.02 * largest
    explained = (basis.columns**2).sum(1)
    assert np.all(basis.residual_variance >= np.diag(exact) - explained - 1e-6 * largest)
    # a threshold above all but the leading eigenvalues keeps only those
    few = emulator.error_basis(x, theta, threshold=0.1 * largest)
    assert 1 <= few.columns.shape[1] < basis.columns.shape[1] and not few.rank_capped


# ---- agreement with the exact programs ---------------------------------------

def _assert_agrees(scalable_fit, exact_fit, mean_tolerance: float, sd_tolerance: float) -> None:
    for name in THETA:
        exact, approx = exact_fit.theta_summary()[name], scalable_fit.theta_summary()[name]
        assert abs(approx["mean"] - exact["mean"]) <= mean_tolerance * exact["sd"], (name, approx, exact)
        assert abs(approx["sd"] / exact["sd"] - 1) <= sd_tolerance, (name, approx, exact)


@pytest.fixture(scope="session")
def sensor_small():
    return sensor_data(150, 150, seed=5, discrepancy=0.8)


@pytest.fixture(scope="session")
def koh_hsgp_fit(sensor_small):
    # a basis given by hand (one fit, not the check's two), wide over T0, along which the discrepancy is
    # linear: the basis check says the short length scale it finds over T0 is near the basis's resolution.
    # The tests below check the bands against those stored at fit time, not the approximation (the slow
    # test does that), so the basis is small: 7 x 10 functions. A gradient costs O(N B + B^3): with
    # 11 x 20 (B = 220 > N = 150) this fixture took 230 s, with 7 x 10 13 s
    with no_stancal_warnings(allow="Hilbert-space discrepancy's basis"):
        return fit(sensor_small, simulator=SENSOR / "simulator.stan", method="koh", approximation="hsgp",
                   basis_functions=(7, 10), boundary_factor=(2.368, 4.736), chains=4, warmup=400, draws=400,
                   adapt_delta=0.95)  # at 4 x (300 + 300) theta's R-hat was 1.012


@pytest.mark.slow
def test_koh_hsgp_agrees_with_exact_koh(sensor_small):
    """Same data, same priors: theta's posterior mean within 0.2 exact
    posterior sd and its sd within 20 % (the issue's bar). With the length
    scale's prior truncated at the basis's longest, k's sd came out 23 % and
    Ta's 43 % below the exact ones; the programs now cap the length scale
    instead (measured at n = 300 in the test below)."""
    koh_hsgp_fit = fit(sensor_small, simulator=SENSOR / "simulator.stan", method="koh",
                       approximation="hsgp", chains=4, warmup=500, draws=500, adapt_delta=0.95)
    # the reference: 2 divergences at adapt_delta 0.9, R-hat 1.012 on delta_sd at 500 + 500
    exact = fit(sensor_small, simulator=SENSOR / "simulator.stan", method="koh", approximation="exact",
                chains=4, warmup=1000, draws=1000, adapt_delta=0.95)
    assert koh_hsgp_fit.method == "koh_hsgp" and exact.method == "koh"
    assert_healthy(exact, divergences=4)  # 1 of 4,000 measured: 0.1 % allowed on the reference
    assert_healthy(koh_hsgp_fit, divergences=2)  # 1 of 2,000 measured at adapt_delta 0.95
    print({name: (koh_hsgp_fit.theta_summary()[name], exact.theta_summary()[name]) for name in THETA})
    _assert_agrees(koh_hsgp_fit, exact, 0.2, 0.2)


def test_hsgp_predictions_carry_the_discrepancy_band(koh_hsgp_fit, sensor_small):
    """At new points the bands come from fresh basis-weight draws (not one
    fixed draw): delta's band at a fitted point matches the one stored at
    fit time, and the gap is located without an n x n solve."""
    assert_healthy(koh_hsgp_fit, divergences=2)  # 1 of 2,000 measured at adapt_delta 0.95 (slow test above)
    points = sensor_small.physical[["t", "T0"]].iloc[:20].reset_index(drop=True)
    table = koh_hsgp_fit.predict(points)
    stored = np.asarray(koh_hsgp_fit.idata["at_observations"]["delta_gp"]).reshape(-1, 150)[:, :20]
    width = table.delta_q95 - table.delta_q05
    stored_width = np.quantile(stored, 0.95, axis=0) - np.quantile(stored, 0.05, axis=0)
    np.testing.assert_allclose(width, stored_width, rtol=0.25)
    from stancal.diagnosing.gap_location import locate_gap
    location = locate_gap(koh_hsgp_fit, max_draws=50)
    assert location.importance["t"]["mean"] > 0.5  # the discrepancy is mostly a function of t


def test_prediction_outside_the_basis_boundary_names_the_input(koh_hsgp_fit):
    far = pd.DataFrame({"t": [400.0], "T0": [70.0]})
    with pytest.raises(ValueError, match="outside the Hilbert-space discrepancy's boundary in 't'"):
        koh_hsgp_fit.predict(far)


@pytest.mark.slow
@pytest.mark.parametrize("method, size", [
    ("koh", 300), ("modular", 300),
    pytest.param("modular", 100, marks=pytest.mark.xfail(strict=True, reason=(
        "measured: theta's sd 25 % (k) and 44 % (Ta) short of the exact one beside a discrepancy of 0.8; "
        "the emulator's covariance enters at one theta, the discrepancy through 100 points' basis")))])
def test_scalable_path_agrees_with_exact(method, size):
    """The issue's figure: at n = N = 300 the scalable path's theta mean lies
    within 0.2 exact posterior sd of the exact one and its sd within 20 %.
    At 100 runs the emulator's error is as large as the noise and correlated
    across the points; carried as one independent variance it left theta's
    sd 3.1 and 3.4 times the exact one (the scaling benchmark's n = N = 100)."""
    data = sensor_data(size, size, seed=6, discrepancy=0.8)
    length = 1000 if method == "koh" else 500  # the exact modular at 300 took 73 minutes at 500 + 500
    settings = {"method": method, "chains": 4, "warmup": length, "draws": length, "adapt_delta": 0.95,
                    "simulator": SENSOR / "simulator.stan" if method == "koh" else None}
    exact = fit(data, approximation="exact", **settings)
    approx = fit(data, approximation="hsgp", **settings)
    assert approx.method == f"{method}_hsgp"
    print({name: (approx.theta_summary()[name], exact.theta_summary()[name]) for name in THETA})
    assert_healthy(exact, divergences=10)  # the reference: 7 of 4,000 measured for modular at n = N = 100
    assert_healthy(approx)
    _assert_agrees(approx, exact, 0.2, 0.2)


@pytest.mark.slow
def test_sensor_log_case_study_through_the_cli(tmp_path):
    """n = N = 5,000 from the shipped CSVs: the scalable path, theta's 90 %
    interval covers the generating truth, a healthy sampler."""
    import json

    from stancal.cli import main

    assert main(["calibrate", str(SENSOR / "config.toml"), "--out", str(tmp_path), "--warmup", "500",
                  "--draws", "500", "--seed", "1"]) == 0
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert_healthy_summary(summary["diagnostics"])
    assert summary["method"] == "modular_hsgp"
    for name, truth in (("k", sensor_physics.K_TRUE), ("Ta", sensor_physics.TA_TRUE)):
        assert summary["theta"][name]["q05"] <= truth <= summary["theta"][name]["q95"]


@pytest.mark.slow
def test_gap_diagnosis_runs_on_the_scalable_path(tmp_path):
    """Past the exact limit every fit of the gap diagnosis (baseline,
    candidates, any refits) stays on the scalable path, and it still finds
    a withheld effect of the inputs: a heat loss growing as t (T0 - 55),
    given as a formula candidate beside a decoy column."""
    from stancal.diagnosing.gap import Candidate, diagnose_gap
    from stancal.reporting.gap_report import write_gap_report

    rng = np.random.default_rng(8)
    cool_downs, readings = 24, 50  # n = 1,200 > EXACT_SIZE_LIMIT
    T0 = np.repeat(rng.uniform(55, 95, cool_downs), readings)
    t = np.tile(np.linspace(0, 60, readings), cool_downs)
    loss = 0.002 * t * (T0 - 55)
    physical = pd.DataFrame({"t": t, "T0": T0, "door": rng.integers(0, 2, t.size),
                             "temperature": newton(t, T0, 0.045, 21.3) - loss + 0.3 * rng.standard_normal(t.size)})
    data = stancal.CalibrationData(physical, ["t", "T0"], "temperature", THETA)
    candidates = [Candidate("heat_loss", formula="I(t * (T0 - 55))"), Candidate("door", formula="door")]
    with no_stancal_warnings():
        analysis = diagnose_gap(data, candidates, simulator=SENSOR / "simulator.stan", method="koh", seed=3,
                                chains=4, warmup=300, draws=300)
    assert_healthy(analysis.baseline)
    for candidate in analysis.candidates:
        assert_healthy(candidate.result)
    assert {analysis.baseline.method, *(c.result.method for c in analysis.candidates)} == {"koh_hsgp"}
    summary = write_gap_report(analysis, tmp_path)
    ranked = {c["name"]: c for c in summary["candidates"]}
    print({name: (c["elpd_diff"], c["elpd_diff_se"], c["shrinkage"]["mean"]) for name, c in ranked.items()})
    assert summary["candidates"][0]["name"] == "heat_loss"
    assert ranked["heat_loss"]["shrinkage"]["mean"] > 0.5
    assert ranked["door"]["shrinkage"]["mean"] < 0.2
    assert (tmp_path / "report.md").is_file()
