"""Stochastic simulators (issue 33, item 3): replicated runs found and
reported, the emulator of the simulator's mean with each run's intrinsic
variance on its diagonal (stochastic kriging, Ankenman, Nelson & Staum
2010), modular.stan against a numpy reference, and the stochastic_cooling
case study (a known truth) against the deterministic emulator."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from conftest import assert_healthy, case_study_module, fit, no_stancal_warnings
from scipy import stats

import stancal
from stancal.fitting.plan import model_options, plan_scalar
from stancal.fitting.run_variance import intrinsic_variance
from stancal.numerics.intrinsic_variance import IntrinsicVariance, log_variance_moments
from stancal.numerics.kernels import ard_cross_cov
from stancal.problem.config import load_config
from stancal.problem.run_replicates import RunReplicates
from stancal.reporting.report import replicated_run_lines
from stancal.stan.standata import build_stan_data, run_intrinsic_variance, to_stan_json

CASE = Path(__file__).parents[1] / "case_studies" / "stochastic_cooling"


@pytest.fixture(scope="module")
def case() -> stancal.CalibrationData:
    return load_config(CASE / "config.toml").data


def small_case(settings: int = 10, replicates: int = 3, points: int = 6) -> stancal.CalibrationData:
    """The case study's first runs, three of each setting, and physical
    points inside their box: a small problem for exact references."""
    data = load_config(CASE / "config.toml").data
    runs = data.runs.iloc[: 5 * settings].groupby(["t", "T0", "k"], sort=False).head(replicates)
    inside = np.logical_and.reduce([data.physical[c].between(runs[c].min(), runs[c].max()) for c in ("t", "T0")])
    physical = data.physical[inside].iloc[:points].reset_index(drop=True)
    assert len(physical) == points
    return stancal.CalibrationData(physical, ["t", "T0"], "temperature", {"k": (0.02, 0.1)},
                                   runs=runs.reset_index(drop=True))


def test_replicated_runs_are_grouped_and_pooled():
    settings = np.array([[0, 1], [0, 1], [0, 1], [2, 3], [4, 5], [4, 5]], float)
    y = np.array([1.0, 2.0, 3.0, 7.0, 4.0, 6.0])
    replicates = RunReplicates.of(settings, y)
    assert replicates.counts.tolist() == [3, 1, 2]
    np.testing.assert_allclose(replicates.means, [2.0, 7.0, 5.0])
    np.testing.assert_allclose(replicates.variances[[0, 2]], [1.0, 2.0])
    # pooled: (2 * 1 + 1 * 2) / (2 + 1)
    summary = replicates.summary(scale=10.0)
    assert summary == {"runs": 6, "settings": 3, "replicated_settings": 2, "runs_per_replicated_setting": [2, 2.5, 3],
                       "pooled_within_replicate_sd": pytest.approx(10 * np.sqrt(4 / 3))}


def test_stage_one_reports_the_case_studys_replicates_and_its_intrinsic_sd(case, caplog):
    with caplog.at_level(logging.INFO, logger="stancal"):
        surface, summary = intrinsic_variance(case, True, seed=1)
    assert summary["runs"] == 300 and summary["settings"] == 60 and summary["replicated_settings"] == 60
    assert summary["runs_per_replicated_setting"] == [5, 5.0, 5]
    # the true sd, 0.2 10^(t / 60), averages about 0.9 deg C in quadrature over t in [0, 64]
    assert 0.75 < summary["pooled_within_replicate_sd"] < 1.3
    assert "60 of 60 run settings (inputs and theta) are replicated" in caplog.text
    # the surface rises with t, as the truth does tenfold over [0, 60] min
    early, late = (np.sqrt(surface.at(np.array([[t, 0.5, 0.5]]))[0]) * case.scaling.y_scale for t in (0.05, 0.85))
    assert late > 2.5 * early


def test_log_variance_bias_and_spread_are_those_of_normal_samples():
    """log_variance_moments against simulation: the log sample variance of n normal draws."""
    rng = np.random.default_rng(0)
    for n in (2, 5, 20):
        logs = np.log(rng.normal(size=(200_000, n)).var(axis=1, ddof=1))
        bias, variance = log_variance_moments(np.array([n]))
        # Monte Carlo se of the mean: sd / sqrt(200,000) < 0.005
        assert abs(logs.mean() - bias[0]) < 0.02 and abs(logs.var() / variance[0] - 1) < 0.02


def test_a_deterministic_simulators_disagreeing_replicates_are_warned_about(case, caplog):
    with caplog.at_level(logging.WARNING, logger="stancal"):
        surface, summary = intrinsic_variance(case, False, seed=1)
    assert surface is None and summary["stochastic"] is False
    assert "if the simulator is stochastic, set stochastic = true" in caplog.text


def stochastic_kriging(settings, means, counts, intrinsic, xt_new, mean, sd, length, run_variance,
                       setting_variance=0.0):
    """Ankenman, Nelson & Staum (2010), eq. (5) and (6), on the settings'
    averages: the mean and MSE of the simulator's mean at xt_new, with
    Sigma_eps = diag(setting_variance + (run_variance + V_i) / n_i), squared
    exponential kernel; run_variance: what every run has on its own besides
    (the jitter; a deterministic simulator's nugget); setting_variance: what
    a setting's runs share (a stochastic simulator's nugget, the emulator's
    misfit to its mean there, which replicates do not average down)."""
    k_settings = ard_cross_cov(settings, settings, 1, sd, length) + np.diag(
        setting_variance + (run_variance + intrinsic) / counts)
    k_new = ard_cross_cov(xt_new, settings, 1, sd, length)
    prediction = mean + k_new @ np.linalg.solve(k_settings, means - mean)
    mse = ard_cross_cov(xt_new, xt_new, 1, sd, length) - k_new @ np.linalg.solve(k_settings, k_new.T)
    return prediction, mse


def unit_settings(data: stancal.CalibrationData) -> np.ndarray:
    return np.hstack([data.scaling.to_unit(data.runs, data.inputs), data.scaling.to_unit(data.runs, data.theta_names)])


@pytest.fixture(scope="module")
def small():
    """A small case, its replicates, a fitted intrinsic variance surface and fixed hyperparameters."""
    data = small_case()
    replicates = RunReplicates.of(unit_settings(data), data.scaling.standardise(data.runs["temperature"].to_numpy()))
    surface = IntrinsicVariance(0.01, replicates.settings, 0.0, 1.0, np.linspace(-1, 1, len(replicates.counts)),
                                stancal.numerics.scalable_emulator.Hyperparameters(0.0, 1.0, np.full(3, 0.6), 0.0))
    hyper = {"emulator_mean": 0.3, "emulator_sd": 1.2, "emulator_length_scale": [0.5, 0.9, 0.7],
             "emulator_nugget": 0.02, "intrinsic_variance": surface.to_json()}
    return data, replicates, surface, hyper


def test_the_emulator_mean_is_stochastic_krigings_on_the_averages(small):
    """Each run with its intrinsic variance on the diagonal and the nugget
    shared by a setting's replicates (stancal), and each setting's average
    with the nugget plus the variance / n (Ankenman et al.) give one predictor."""
    from stancal.fitting.stage_one import emulator_mean_function

    data, replicates, surface, hyper = small
    assert (replicates.counts == 3).all() and len(replicates.counts) == 10 and not np.allclose(surface.at(replicates.settings), surface.pooled)
    points = data.physical[["t", "T0"]]
    theta_unit = np.array([[0.3], [0.6]])
    ours = data.scaling.standardise(emulator_mean_function(data, hyper, 1)(points, theta_unit))
    for row, theta in zip(ours, theta_unit, strict=True):
        xt = np.hstack([data.scaling.to_unit(points, data.inputs), np.full((len(points), 1), theta)])
        reference, _ = stochastic_kriging(replicates.settings, replicates.means, replicates.counts,
                                          surface.at(replicates.settings), xt, 0.3, 1.2, np.array([0.5, 0.9, 0.7]),
                                          0.0, setting_variance=0.02**2)
        np.testing.assert_allclose(row, reference, rtol=1e-8, atol=1e-8)


def test_modular_stan_density_is_stochastic_krigings(small):
    """modular.stan's log density at several theta against a numpy reference
    built on the settings' averages: y ~ N(m(theta), MSE(theta) + nugget^2 S +
    sigma^2 I), S_ij = 1 where x_i = x_j: the intrinsic variance on the runs
    only, the nugget (the emulator's misfit, one value at one point) at the
    physical points too; a setting's replicates share the nugget (review: it
    sat on each run alone, so n replicates averaged it down to nugget^2 / n);
    to 1e-8, up to a constant."""
    from stancal.stan.backends import get_backend

    data, replicates, surface, hyper = small
    plan = plan_scalar(data, None, "modular", model_options(discrepancy="none", stochastic=True))
    stan_data = build_stan_data(data, plan.program.data, plan.options, data.physical[["t", "T0"]].iloc[:2],
                                emulator_hyperparameters=hyper)
    np.testing.assert_allclose(np.square(stan_data["run_intrinsic_sd"]), run_intrinsic_variance(data, hyper))
    _, log_density = get_backend().log_density_functions(plan.main_program(), to_stan_json(stan_data))
    sigma = 0.05  # the noise sd, standardised
    jitter = 1e-6 * 1.2**2  # functions/gp_kernels.stan's add_jitter: on the runs and on the points
    y = stan_data["y"]
    x = data.scaling.to_unit(data.physical, data.inputs)
    same = (x[:, None, :] == x[None, :, :]).all(axis=2)
    assert same.sum() > len(x)  # two readings at one point share the emulator's misfit
    stan, reference = [], []
    for theta in (0.2, 0.45, 0.7, 0.9):
        stan.append(log_density(np.array([[np.log(theta / (1 - theta)), np.log(sigma)]]))[0]
                    - np.log(theta * (1 - theta)))  # without the Jacobian of theta_unit
        mean, mse = stochastic_kriging(replicates.settings, replicates.means, replicates.counts,
                                       surface.at(replicates.settings), np.hstack([x, np.full((len(x), 1), theta)]),
                                       0.3, 1.2, np.array([0.5, 0.9, 0.7]), jitter, setting_variance=0.02**2)
        covariance = mse + 0.02**2 * same + (sigma**2 + jitter) * np.eye(len(y))
        reference.append(stats.multivariate_normal(mean, covariance).logpdf(y))
    np.testing.assert_allclose(np.diff(stan), np.diff(reference), rtol=1e-8, atol=1e-8)


def emulator_reference(xt, y, u, intrinsic, shared):
    """emulator.stan's log density, written out: y_sim ~ N(m, K + nugget^2 S
    + jitter + diag(V)), S the runs that share a nugget draw (``shared``),
    with its priors and the Jacobian of its log-scale parameters;
    u = (mean, log sd, log length scales, log nugget)."""
    mean, sd, length, nugget = u[0], np.exp(u[1]), np.exp(u[2:-1]), np.exp(u[-1])
    K = ard_cross_cov(xt, xt, 1, sd, length) + nugget**2 * shared + np.diag(1e-6 * sd**2 + intrinsic)
    prior = -0.5 * mean**2 - 0.5 * sd**2 + np.sum(-3 * np.log(length) - 1 / length) - 0.5 * (nugget / 0.05) ** 2
    return stats.multivariate_normal(np.full(len(y), mean), K).logpdf(y) + prior + u[1:].sum()


@pytest.mark.parametrize("stochastic", [True, False])
def test_stage_one_shares_the_nugget_within_a_setting(small, stochastic):
    """Stage 1's objective, emulator.stan's log density and the scalable
    path's (scalable_emulator.negative_log_posterior), against numpy at
    several hyperparameters, to 1e-8 up to a constant: a stochastic
    simulator's replicates share one nugget draw (S_ij = 1 within a setting),
    a deterministic simulator's runs each have their own (S = I, as before)."""
    from stancal.numerics.scalable_emulator import negative_log_posterior
    from stancal.stan.backends import get_backend
    from stancal.stan.standata import build_emulator_data

    data, replicates, surface, hyper = small
    plan = plan_scalar(data, None, "modular", model_options(stochastic=stochastic))
    intrinsic = run_intrinsic_variance(data, hyper if stochastic else {})
    stan_data = {**build_emulator_data(data, plan.options), "run_intrinsic_sd": np.sqrt(intrinsic)}
    _, log_density = get_backend().log_density_functions(plan.stan_programs()[0], to_stan_json(stan_data))
    xt = unit_settings(data)
    same = (xt[:, None, :] == xt[None, :, :]).all(axis=2)
    assert same.sum() == 3 * len(xt)  # three runs per setting
    shared = same if stochastic else np.eye(len(xt))
    rng = np.random.default_rng(4)
    points = [np.concatenate([[rng.normal(0, 0.3), rng.normal(0, 0.2)], np.log(rng.uniform(0.3, 1, 3)),
                              [np.log(rng.uniform(0.01, 0.1))]]) for _ in range(4)]
    reference = [emulator_reference(xt, stan_data["y_sim"], u, intrinsic, shared) for u in points]
    stan = log_density(np.array(points))
    python = [-negative_log_posterior(u, xt, stan_data["y_sim"], intrinsic if stochastic else None)[0]
              for u in points]
    np.testing.assert_allclose(np.diff(stan), np.diff(reference), rtol=1e-8, atol=1e-8)
    np.testing.assert_allclose(np.diff(python), np.diff(reference), rtol=1e-8, atol=1e-8)


def test_the_scalable_nuggets_gradient_with_shared_draws(small):
    """negative_log_posterior's gradient in the log nugget, with replicates
    sharing it, against a central difference (step 1e-5: error ~1e-9)."""
    from stancal.numerics.scalable_emulator import negative_log_posterior

    data, replicates, surface, hyper = small
    xt, y = unit_settings(data), data.scaling.standardise(data.runs["temperature"].to_numpy())
    intrinsic = run_intrinsic_variance(data, hyper)
    u = np.array([0.1, 0.0, np.log(0.5), np.log(0.9), np.log(0.7), np.log(0.05)])
    step = np.zeros_like(u)
    step[-1] = 1e-5
    difference = (negative_log_posterior(u + step, xt, y, intrinsic)[0]
                  - negative_log_posterior(u - step, xt, y, intrinsic)[0]) / 2e-5
    assert negative_log_posterior(u, xt, y, intrinsic)[1][-1] == pytest.approx(difference, rel=1e-6, abs=1e-6)


def test_a_deterministic_modular_density_is_unchanged(small):
    """A deterministic simulator's runs (the same replicated runs, no
    intrinsic variance) keep the nugget each on its own, as before the
    nugget was shared within a setting: modular.stan's log density is
    kriging on every run with nugget^2 + jitter on its diagonal (that is,
    on the settings' averages with it divided by n), to 1e-8."""
    from stancal.stan.backends import get_backend

    data, replicates, surface, hyper = small
    plan = plan_scalar(data, None, "modular", model_options(discrepancy="none"))
    deterministic = {k: v for k, v in hyper.items() if k != "intrinsic_variance"}
    stan_data = build_stan_data(data, plan.program.data, plan.options, data.physical[["t", "T0"]].iloc[:2],
                                emulator_hyperparameters=deterministic)
    assert not np.any(stan_data["run_intrinsic_sd"])
    _, log_density = get_backend().log_density_functions(plan.main_program(), to_stan_json(stan_data))
    sigma, jitter = 0.05, 1e-6 * 1.2**2
    y, x = stan_data["y"], data.scaling.to_unit(data.physical, data.inputs)
    same = (x[:, None, :] == x[None, :, :]).all(axis=2)
    stan, reference = [], []
    for theta in (0.2, 0.45, 0.7, 0.9):
        stan.append(log_density(np.array([[np.log(theta / (1 - theta)), np.log(sigma)]]))[0]
                    - np.log(theta * (1 - theta)))
        mean, mse = stochastic_kriging(replicates.settings, replicates.means, replicates.counts,
                                       np.zeros(len(replicates.counts)), np.hstack([x, np.full((len(x), 1), theta)]),
                                       0.3, 1.2, np.array([0.5, 0.9, 0.7]), 0.02**2 + jitter)
        reference.append(stats.multivariate_normal(mean, mse + 0.02**2 * same + (sigma**2 + jitter) * np.eye(len(y)))
                         .logpdf(y))
    np.testing.assert_allclose(np.diff(stan), np.diff(reference), rtol=1e-8, atol=1e-8)


def test_y_rep_and_new_points_carry_the_misfit_the_data_condition_on(small):
    """At one parameter point, 2,500 runs of modular.stan's generated
    quantities (a stochastic simulator, a nugget of 0.3, standardised):
    f_new at three new points (one at a physical point, which shares its
    misfit) and y_rep at the rows have the mean and sd of the written-out
    model's Gaussian conditional given the runs and the data, with the
    emulator's misfit part of f at every point (review of issue 33: y_rep drew
    the misfit afresh, its sd 5.6 to 6.1 times the reference's here, and
    f_new left it out, 0.65 to 5.4 times, the runs averaging it down too)."""
    from test_source_bias import fixed_parameter_draws, gaussian_conditional

    data, replicates, surface, hyper = small
    hyper = {**hyper, "emulator_nugget": 0.3}
    plan = plan_scalar(data, None, "modular", model_options(discrepancy="none", stochastic=True))
    new = pd.DataFrame({"t": [data.physical["t"][0], 12.0, 30.0], "T0": [data.physical["T0"][0], 70.0, 85.0]})
    d = to_stan_json(build_stan_data(data, plan.program.data, plan.options, new, emulator_hyperparameters=hyper))
    assert d["estimate_rho"] == 0 and d["H"] == 0 and d["kernel_id"] == 1
    theta, sigma, nugget, sd, length = 0.4, 0.05, 0.3, 1.2, np.array([0.5, 0.9, 0.7])
    point = {"theta_unit": [theta], "noise_sd": [sigma]}  # every other parameter is empty here
    draws = 2500
    drawn = fixed_parameter_draws(plan.main_program(), d, point, draws)
    # the reference, standardised: runs with the nugget shared within a setting and V on the diagonal
    sim, x = unit_settings(data), data.scaling.to_unit(data.physical, data.inputs)
    xt, xt_new = (np.hstack([a, np.full((len(a), 1), theta)]) for a in (x, data.scaling.to_unit(new, data.inputs)))
    jitter = 1e-6 * sd**2

    def f_cov(a, b):  # the emulator at points of one theta: its GP and its misfit, one value at one point
        return ard_cross_cov(a, b, 1, sd, length) + nugget**2 * (a[:, None, :] == b[None, :, :]).all(-1)

    runs = f_cov(sim, sim) + np.diag(run_intrinsic_variance(data, hyper) + jitter)
    cross = ard_cross_cov(sim, xt, 1, sd, length)
    cov = np.block([[runs, cross], [cross.T, f_cov(xt, xt) + (sigma**2 + jitter) * np.eye(len(xt))]])
    resid = np.concatenate([d["y_sim"], d["y"]]) - 0.3
    for name, points, fresh in (("f_new", xt_new, 0.0), ("y_rep", xt, sigma**2)):
        mean, covariance = gaussian_conditional(cov, resid, np.hstack([ard_cross_cov(points, sim, 1, sd, length),
                                                                        f_cov(points, xt)]), f_cov(points, points))
        mean = d["y_center"] + d["y_scale"] * (0.3 + mean)
        sd_reference = d["y_scale"] * np.sqrt(np.diag(covariance) + fresh)
        values = drawn[name]
        # the sd of 2,500 normal draws has relative se 1.4 %, their mean se sd / 50: 7 % and 5 se hold
        # every point with room (a 5-se miss has probability 6e-7 per point)
        np.testing.assert_allclose(values.std(axis=1), sd_reference, rtol=0.07, err_msg=name)
        assert np.all(np.abs(values.mean(axis=1) - mean) <= 5 * sd_reference / np.sqrt(draws)), name


@pytest.mark.parametrize(("keywords", "match"), [
    ({"simulator": "case_studies/cooling/simulator.stan"}, "a Stan simulator is a deterministic function"),
    ({"method": "koh_emulator"}, "stochastic = true runs on the programs modular, modular_hsgp"),
])
def test_stochastic_refuses_what_it_cannot_run(case, keywords, match):
    with pytest.raises(ValueError, match=match):
        plan_scalar(case, keywords.get("simulator"), keywords.get("method"), model_options(stochastic=True))


def test_stochastic_needs_replicated_runs(case):
    distinct = case.runs.drop_duplicates(["t", "T0", "k"])
    data = stancal.CalibrationData(case.physical, ["t", "T0"], "temperature", {"k": (0.02, 0.1)}, runs=distinct)
    with pytest.raises(ValueError, match="needs replicated runs"):
        plan_scalar(data, None, None, model_options(stochastic=True))


def test_stochastic_chooses_modular_by_default(case):
    assert plan_scalar(case, None, None, model_options(stochastic=True)).program.name == "modular"


def test_the_config_key_reaches_the_model_options():
    assert load_config(CASE / "config.toml").model["stochastic"] is True


def test_the_deterministic_emulator_takes_the_simulators_noise_for_its_misfit(case):
    """Stage 1 alone: the deterministic emulator's nugget is the runs' pooled
    scatter (about 1 deg C), carried to the physical points as misfit; the
    stochastic emulator's nugget, with the scatter on the runs' diagonal and
    the nugget one value per setting, is its misfit to the simulator's mean:
    0.29 deg C against 1.14 here (seed 1), a quarter (with a nugget of each
    run's own it was 0.07, a setting's share 0.07 / sqrt(5) = 0.03)."""
    from stancal.fitting.stage_one import run_stage_one
    from stancal.stan.backends import get_backend

    nuggets = {}
    for stochastic in (False, True):
        plan = plan_scalar(case, None, "modular", model_options(stochastic=stochastic))
        emulator = run_stage_one(plan.stage_one, case, plan.options, plan.stan_programs(), backend=get_backend(),
                                 seed=1)
        nuggets[stochastic] = emulator["hyperparameters"]["emulator_nugget"] * case.scaling.y_scale
    assert 0.7 < nuggets[False] < 1.5
    assert nuggets[True] < 0.4 * nuggets[False]  # 0.25 measured: the stage-1 optimum is deterministic given the seed


@pytest.mark.slow  # a fit with stage 1 on 300 runs, about a minute: the default run checks the model against numpy
def test_the_stochastic_fit_recovers_k_and_the_measurement_sd(case, tmp_path):
    """A small fit of the case study (truth k = 0.05 1/min, measurement sd
    0.1 deg C): k's 90 % interval holds the truth and is narrow (0.0018
    at 2 x (800 + 800); the deterministic emulator's 0.0053: docs/noise.md),
    the noise sd is the measurement's; the summary and the report state the
    replicated runs."""
    make_data = case_study_module(CASE)
    with no_stancal_warnings():
        result = fit(case, method="modular", discrepancy="none", stochastic=True)
    assert_healthy(result)
    k = np.asarray(result.idata["posterior"]["theta"]).ravel()
    low, high = np.quantile(k, [0.05, 0.95])
    assert low <= make_data.K_TRUE <= high and high - low < 0.004
    noise = np.asarray(result.idata["posterior"]["noise_sd"]).ravel()  # original units
    assert np.quantile(noise, 0.05) < make_data.MEASUREMENT_SD < np.quantile(noise, 0.95)
    assert result.emulator["replicated_runs"]["replicated_settings"] == 60
    summary = result.to_summary_json()  # report.md's lines from summary.json's entry (a whole report takes minutes)
    assert summary["emulator"]["replicated_runs"]["runs_per_replicated_setting"] == [5, 5.0, 5]
    report = "\n".join(replicated_run_lines(summary["emulator"]))
    assert "## Replicated simulator runs" in report and "60 of 60 run settings" in report
    assert "stochastic simulator: the emulator of its mean carries its own sd" in report
    # saved and loaded, the fit keeps its option and its intrinsic variance surface
    loaded = stancal.CalibrationResult.load(result.save(tmp_path / "fit.nc"))
    assert loaded.options.stochastic
    np.testing.assert_allclose(run_intrinsic_variance(case, loaded.emulator["hyperparameters"]),
                               run_intrinsic_variance(case, result.emulator["hyperparameters"]))


def test_the_scalable_emulator_is_stochastic_krigings_too(small):
    """modular_hsgp's stage 1 (stancal.numerics.scalable_emulator) with the
    intrinsic variance and the nugget shared by a setting's replicates: its
    mean and its variance at the points (the local GP's, all runs neighbours
    in this small case, plus the nugget, its misfit there) are stochastic kriging's."""
    from stancal.numerics.scalable_emulator import JITTER, ScalableEmulator, exact_mean
    from stancal.stan.standata import emulator_run_data

    data, replicates, surface, hyper = small
    runs = emulator_run_data(data)
    stored = {**hyper, "theta_degrees": [4]}
    emulator = ScalableEmulator.of(runs["x_sim"], runs["theta_sim"], runs["y_sim"], stored,
                                   run_intrinsic_variance(data, hyper))
    x = data.scaling.to_unit(data.physical, data.inputs)
    theta = np.array([0.4])
    mean = 0.3 + exact_mean(x, runs["x_sim"], runs["theta_sim"], emulator.alpha, emulator.hyperparameters,
                            theta[None, :])[:, 0]
    reference, mse = stochastic_kriging(replicates.settings, replicates.means, replicates.counts,
                                        surface.at(replicates.settings), np.hstack([x, np.full((len(x), 1), 0.4)]),
                                        0.3, 1.2, np.array([0.5, 0.9, 0.7]), JITTER * 1.2**2,
                                        setting_variance=0.02**2)
    np.testing.assert_allclose(mean, reference, rtol=1e-8, atol=1e-8)
    np.testing.assert_allclose(emulator.variance(x, theta), np.diag(mse) + 0.02**2, rtol=1e-6, atol=1e-10)


def test_modular_hsgp_carries_the_misfit_at_the_experiments(small):
    """modular_hsgp against the numpy reference of modular's density (review
    of issue 33: it carried V on the runs but no nugget at the experiments,
    so crossing the size limit changed the model). At the theta where its
    emulator error is taken (0.5, a Chebyshev node of the mean's degree 4:
    the mean is exact there) and with every eigenvector kept, its error
    covariance is stochastic kriging's MSE plus nugget^2 S, S_ij = 1 where
    two physical points are one, and its log density across the noise sd is
    modular's, y ~ N(m, MSE + nugget^2 S + sigma^2 I); to 1e-6 (the local
    GP's jitter on the runs, 1e-6 of the GP's variance, is the gap)."""
    from stancal.numerics.scalable_emulator import JITTER
    from stancal.stan.backends import get_backend

    data, replicates, surface, hyper = small
    hyper = {**hyper, "theta_degrees": [4], "variance_theta": [0.5], "error_threshold": 1e-12}
    plan = plan_scalar(data, None, "modular_hsgp", model_options(discrepancy="none", stochastic=True))
    stan_data = build_stan_data(data, plan.program.data, plan.options, data.physical[["t", "T0"]].iloc[:2],
                                emulator_hyperparameters=hyper)
    x = data.scaling.to_unit(data.physical, data.inputs)
    same = (x[:, None, :] == x[None, :, :]).all(axis=2)
    mean, mse = stochastic_kriging(replicates.settings, replicates.means, replicates.counts,
                                   surface.at(replicates.settings), np.hstack([x, np.full((len(x), 1), 0.5)]),
                                   0.3, 1.2, np.array([0.5, 0.9, 0.7]), JITTER * 1.2**2, setting_variance=0.02**2)
    error = mse + 0.02**2 * same  # the emulator's error at the points, its misfit included
    basis = np.asarray(stan_data["emulator_error_basis"])
    np.testing.assert_allclose(basis @ basis.T + stan_data["emulator_variance"] * np.eye(len(x)), error,
                               rtol=1e-6, atol=1e-9)
    _, log_density = get_backend().log_density_functions(plan.main_program(), to_stan_json(stan_data))
    sigmas = np.array([0.03, 0.05, 0.1, 0.2])
    stan = log_density(np.column_stack([np.zeros(4), np.log(sigmas)]))  # theta_unit = 0.5
    reference = [stats.multivariate_normal(mean, error + sigma**2 * np.eye(len(x))).logpdf(stan_data["y"])
                 - 0.5 * sigma**2 + np.log(sigma) for sigma in sigmas]  # its half-normal prior, its Jacobian
    np.testing.assert_allclose(np.diff(stan), np.diff(reference), rtol=1e-6, atol=1e-6)


def _basis_case(points: np.ndarray, nugget: float, threshold: float):
    """error_basis at theta = 0.5 of 400 random runs in (x, theta) and a
    GP of sd 1, length scales 0.3; the exact GP part of its covariance."""
    from stancal.numerics import scalable_emulator as scalable

    xt = np.random.default_rng(3).uniform(size=(400, 2))
    h = scalable.Hyperparameters(0.0, 1.0, np.array([0.3, 0.3]), nugget)
    basis = scalable.error_basis(points, np.array([0.5]), xt, h, threshold)
    at = np.column_stack([points, np.full(len(points), 0.5)])
    cross = scalable.se_correlation(at, xt, h.length_scale)
    exact = scalable.se_correlation(at, at, h.length_scale) - cross @ np.linalg.solve(
        scalable.run_covariance(xt, h), cross.T)
    return basis, exact


def test_the_error_basis_rank_at_distinct_points_is_the_gps_not_the_nuggets():
    """Review of issue 33: nugget^2 S in the Nystroem matrix raised every
    eigenvalue by nugget^2 where the points are distinct (S = I), so a
    nugget above the DEFAULT threshold (ERROR_RANK_SHARE of the residual
    variance; for a residual sd of 0.1, 3e-4) took the rank to
    MAX_ERROR_RANK, capped: 40 columns of white noise. At distinct points
    the nugget is on the independent residual; the columns are the GP
    part's eigenvalues above the threshold (6 of them at nugget 0.02, which
    also widens the GP part through the runs' diagonal), which they leave
    at most the threshold of (measured 2.5e-4 against 3e-4)."""
    from stancal.numerics.scalable_emulator import ERROR_RANK_SHARE

    points = np.random.default_rng(4).uniform(size=(120, 1))
    threshold = ERROR_RANK_SHARE * 0.1**2
    basis, exact = _basis_case(points, 0.02, threshold)
    assert basis.columns.shape[1] == np.sum(np.linalg.eigvalsh(exact) > threshold) < 40
    assert not basis.rank_capped
    assert np.linalg.norm(exact - basis.columns @ basis.columns.T, 2) <= threshold
    assert np.all(basis.residual_variance >= 0.02**2)


def test_every_group_of_identical_points_shares_its_misfit_beyond_the_landmarks():
    """With more points than LANDMARKS (610 distinct, the first 10 twice), a
    group with no landmark among it still shares one nugget draw: the
    columns carry nugget^2 between the two points of every group, over the
    GP's covariance there (to 1e-9; measured 1e-13 at seed 4, 19 columns,
    all of C's eigenvalues above 1e-4 kept)."""
    from stancal.numerics.scalable_emulator import LANDMARKS

    distinct = np.random.default_rng(4).uniform(size=(LANDMARKS + 10, 1))
    points = np.vstack([distinct, distinct[:10]])
    basis, exact = _basis_case(points, 0.1, 1e-4)
    assert not basis.rank_capped
    first, second = np.arange(10), LANDMARKS + 10 + np.arange(10)
    shared = (basis.columns[first] * basis.columns[second]).sum(1) - exact[first, second]
    np.testing.assert_allclose(shared, 0.1**2, atol=1e-9)


@pytest.mark.slow
def test_the_scalable_path_takes_a_stochastic_simulator(case):
    """modular_hsgp with the intrinsic variance on its precomputed-weight
    emulator's runs: a healthy fit whose k interval holds the truth. The
    scalable path takes the emulator's covariance at theta's least-squares
    fit, and says so when the posterior's theta moves an observation's sd by
    more than its tolerance: here the emulator's sd at the points (about
    0.4 deg C) is four times the noise's, so it does; the exact path has no
    such approximation."""
    make_data = case_study_module(CASE)
    with no_stancal_warnings(allow="the emulator's covariance entered the fit at theta's least-squares fit"):
        result = fit(case, method="modular", approximation="hsgp", discrepancy="none", stochastic=True)
    assert result.method == "modular_hsgp"
    assert_healthy(result)
    assert result.emulator["hyperparameters"]["intrinsic_variance"]["hyperparameters"] is not None
    k = np.asarray(result.idata["posterior"]["theta"]).ravel()
    assert np.quantile(k, 0.05) <= make_data.K_TRUE <= np.quantile(k, 0.95)


@pytest.mark.slow
def test_the_case_studys_comparison(tmp_path):
    """compare.py at 2 x (800 + 800): both fits healthy and covering k; the
    deterministic emulator's k interval at least 1.5 times the stochastic
    one's (measured 2.04, one run; 2.9 before the nugget per setting); both
    fits' 90 % bands covering 0.75-0.98 of the held-out replicates in both
    halves (measured 0.85 and 0.85 each: the replicates sit at the fitted
    settings, where both fits condition the emulator's misfit on the
    readings); at settings without readings, where the misfit is not
    conditioned, the deterministic bands at least 1.5 times as wide as the
    stochastic ones in both halves (measured 2.8 and 2.6, one run); the
    stochastic fit's noise sd interval holds 0.1 deg C."""
    compare = case_study_module(CASE, "compare")
    table = compare.main(tmp_path, draws=800, chains=2).set_index("emulator")
    assert (table["max_rhat"] <= 1.01).all() and (table["divergences"] == 0).all()
    assert table["k_covers_truth"].all()
    assert table.loc["deterministic", "k_width_90"] > 1.5 * table.loc["stochastic", "k_width_90"]
    assert table.loc["stochastic", "noise_sd_q05"] < compare.MEASUREMENT_SD < table.loc["stochastic", "noise_sd_q95"]
    halves = ["coverage_fitted_quiet", "coverage_fitted_noisy"]
    assert table[halves].apply(lambda c: c.between(0.75, 0.98)).all().all()
    new = ["band_width_new_quiet", "band_width_new_noisy"]
    assert (table.loc["deterministic", new] > 1.5 * table.loc["stochastic", new]).all(), table[new]


def test_the_gap_diagnosis_plans_with_the_stochastic_emulator(case):
    """`stancal gap` passes [simulator] stochastic on as a calibrate option;
    its baseline's plan (make_plan of the options' model keywords) keeps it."""
    from stancal.fitting.plan import make_plan, model_keywords

    plan = make_plan(case, None, None, None, **model_keywords({"stochastic": True, "chains": 2}, False))
    assert plan.name == "modular" and plan.options.stochastic


def test_a_setting_without_scatter_leaves_the_variance_surface_to_the_others():
    """Discrete Monte Carlo output often repeats itself at a setting: that
    setting's log sample variance is -inf and tells nothing of the surface,
    so the surface is fitted to the other settings; equal variances
    everywhere (no surface to tell from a level) give the pooled variance."""
    from stancal.numerics.intrinsic_variance import IntrinsicVariance

    settings = np.linspace(0, 1, 12)[:, None]
    variances = 0.04 * np.exp(2 * settings[:, 0])  # a variance rising over the input
    counts = np.full(12, 5)
    surface = IntrinsicVariance.fit(settings, counts, np.where(np.arange(12) == 3, 0.0, variances), seed=1)
    assert surface.hyperparameters is not None and len(surface.settings) == 11
    assert surface.at(np.array([[1.0]]))[0] > 2 * surface.at(np.array([[0.0]]))[0]
    level = IntrinsicVariance.fit(settings, counts, np.full(12, 0.04), seed=1)
    assert level.hyperparameters is None and level.pooled == pytest.approx(0.04)
