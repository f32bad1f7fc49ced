"""koh_emulator with runs of cheaper simulators (docs/multifidelity.md, the
joint path): every level's GP and the scale between levels sampled with
theta, all runs of all levels and the readings in one Gaussian likelihood
(Kennedy & O'Hagan 2000, section 3; Goh et al. 2013). Its log density
against the AR(1) model written out in numpy and scipy; the plan's
refusals, one line each before any compile; a calibration on the two-level
cooling problem of tests/test_multifidelity.py against modular on the same
data (-m slow). One compile: koh_emulator.stan."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import assert_healthy, assert_log_density_is, fit, se
from scipy import stats
from test_multifidelity import K_TRUE, problem

import stancal
from stancal.fitting.inits import fidelity_emulator_inits
from stancal.fitting.plan import make_plan, plan_scalar
from stancal.fitting.stage_one import as_chain_starts
from stancal.stan.registry import JOINT_FIDELITY_RUN_LIMIT
from stancal.stan.standata import build_stan_data, to_stan_json


def ar1_cov(level_a: int, level_b: int, xt_a: np.ndarray, xt_b: np.ndarray, p: dict) -> np.ndarray:
    """cov(f_a(s), f_b(t)) of the autoregressive emulator by its recursion
    (Kennedy & O'Hagan 2000, section 2): f_1 = g_1, f_k = rho_k f_(k-1) + g_k
    with independent g_k, levels numbered from 1, the top level's GP the
    emulator_* parameters and the cheaper ones' low_emulator_*."""
    if level_a < level_b:
        return ar1_cov(level_b, level_a, xt_b, xt_a, p).T
    sds = [*p["low_emulator_sd"], p["emulator_sd"]]
    lengths = [*p["low_emulator_length_scale"], p["emulator_length_scale"]]
    if level_a > level_b:  # f_a = rho_a f_(a-1) + g_a, and g_a is independent of f_b
        return p["level_rho"][level_a - 2] * ar1_cov(level_a - 1, level_b, xt_a, xt_b, p)
    own = se(xt_a, xt_b, sds[level_a - 1], lengths[level_a - 1])
    if level_a == 1:
        return own
    return p["level_rho"][level_a - 2] ** 2 * ar1_cov(level_a - 1, level_a - 1, xt_a, xt_b, p) + own


def ar1_mean(level: int, p: dict) -> float:
    """E f_k: the level's own GP mean plus the scaled mean of the level below."""
    means = [*p["low_emulator_mean"], p["emulator_mean"]]
    return means[0] if level == 1 else p["level_rho"][level - 2] * ar1_mean(level - 1, p) + means[level - 1]


def numpy_ar1_log_density(d: dict, p: dict) -> float:
    """log p(theta, the parameters, every level's runs, y) of koh_emulator.stan
    up to a constant: [y_sim; y] normal with the AR(1) emulator's mean and
    covariance at each run's level and at the top level for the readings
    (ar1_cov), each run's level's nugget on its diagonal, delta's kernel and
    the noise among the readings, the jitter 1e-6 times the top level's prior
    variance, and the priors of functions/priors.stan (the cheaper levels'
    as the top level's; level_rho normal(1, 0.5))."""
    x, levels, top = np.asarray(d["x"]), np.asarray(d["run_level"]), d["L"]
    xt_sim = np.column_stack([d["x_sim"], d["theta_sim"]])
    xt_obs = np.column_stack([x, np.tile(p["theta_unit"], (len(x), 1))])
    points = [(level, xt[None, :]) for level, xt in zip(levels, xt_sim, strict=True)] + [
        (top, xt[None, :]) for xt in xt_obs]
    cov = np.block([[ar1_cov(a, b, s, t, p) for b, t in points] for a, s in points])
    m = len(levels)
    nuggets = np.asarray([*p["low_emulator_nugget"], p["emulator_nugget"]])
    cov[:m, :m] += np.diag(nuggets[levels - 1] ** 2)
    cov[m:, m:] += se(np.asarray(d["x_delta"]), np.asarray(d["x_delta"]), p["delta_sd"][0],
                      p["delta_input_length_scale"]) + p["noise_sd"][0] ** 2 * np.eye(len(x))
    cov += 1e-6 * ar1_cov(top, top, xt_obs[:1], xt_obs[:1], p)[0, 0] * np.eye(len(cov))
    mean = np.array([ar1_mean(level, p) for level, _ in points])
    y = np.concatenate([d["y_sim"], d["y"]])
    sds = np.array([*p["low_emulator_sd"], p["emulator_sd"]])
    priors = (stats.norm(0, 1).logpdf(p["noise_sd"]).sum() + stats.norm(0, 0.5).logpdf(p["delta_sd"]).sum()
              + stats.invgamma(3, scale=1).logpdf(p["delta_input_length_scale"]).sum()
              + stats.norm(0, 1).logpdf([*p["low_emulator_mean"], p["emulator_mean"]]).sum()
              + stats.norm(0, 1).logpdf(sds).sum()
              + stats.norm(0, 0.05).logpdf([*p["low_emulator_nugget"], p["emulator_nugget"]]).sum()
              + stats.invgamma(2, scale=1).logpdf(
                  np.concatenate([np.ravel(p["low_emulator_length_scale"]), p["emulator_length_scale"]])).sum()
              + stats.norm(1, 0.5).logpdf(p["level_rho"]).sum())
    return float(stats.multivariate_normal(mean, cov).logpdf(y) + priors)


def ar1_points(d: dict, rng: np.random.Generator) -> list[dict]:
    """Three parameter points of the two-level program, every level's GP its own."""
    low = d["L"] - 1
    return [{"theta_unit": [rng.uniform(0.1, 0.9)], "noise_sd": [rng.uniform(0.01, 0.1)],
             "delta_sd": [rng.uniform(0.1, 0.5)], "delta_input_length_scale": [rng.uniform(0.2, 1.0)],
             "emulator_mean": rng.normal(0, 0.3), "emulator_sd": rng.uniform(0.1, 0.5),
             "emulator_length_scale": rng.uniform(0.3, 1.0, 2).tolist(), "emulator_nugget": rng.uniform(0.001, 0.02),
             "level_rho": rng.uniform(0.5, 1.5, low).tolist(), "low_emulator_mean": rng.normal(0, 0.3, low).tolist(),
             "low_emulator_sd": rng.uniform(0.5, 1.5, low).tolist(),
             "low_emulator_length_scale": rng.uniform(0.3, 1.0, (low, 2)).tolist(),
             "low_emulator_nugget": rng.uniform(0.001, 0.02, low).tolist(),
             "nu": [], "noise_weight": [], "noise_gp_sd": [], "noise_length_scale": [], "noise_z": [],
             "rho_free": [], "beta": [], "delta_relevance": [], "bias_sd": [], "bias_length_scale": []}
            for _ in range(3)]


def test_the_joint_multifidelity_log_density_is_the_numpy_ar1_one():
    """koh_emulator.stan with 8 cheap and 4 expensive runs and 12 readings, at
    three parameter points, against the AR(1) model written out by its
    recursion: log density differences agree to 1e-8."""
    data = problem(low=8, high=4)
    plan = make_plan(data, method="koh_emulator")
    stan_data = to_stan_json(build_stan_data(data, plan.program.data, plan.options, data.physical.iloc[:2]))
    assert stan_data["L"] == 2 and stan_data["run_level"] == [1] * 8 + [2] * 4 and stan_data["M"] == 12
    assert_log_density_is(plan.main_program(), stan_data, ar1_points(stan_data, np.random.default_rng(5)),
                          numpy_ar1_log_density)


# ---- the plan: opt-in, refusals before any compile ----------------------------------------------

def test_koh_emulator_takes_low_fidelity_runs_when_asked_and_modular_stays_the_default():
    data = problem(low=10, high=4)
    assert plan_scalar(data).name == "modular"  # the default takes any number of runs
    plan = plan_scalar(data, method="koh_emulator")
    assert plan.name == "koh_emulator" and plan.fidelities == 2 and plan.stage_one == "fidelity_emulator"


def test_the_joint_path_refuses_a_linear_rho_and_too_many_runs_in_one_line():
    with pytest.raises(ValueError, match=r"^\[simulator.low_fidelity\] rho = 'linear': method 'koh_emulator' "
                                         r"takes a scale of form constant only; use method modular"):
        plan_scalar(problem(low=10, high=8, low_fidelity_rho="linear"), method="koh_emulator")
    many = problem(low=JOINT_FIDELITY_RUN_LIMIT - 3, high=4)
    with pytest.raises(ValueError, match=rf"at most {JOINT_FIDELITY_RUN_LIMIT} runs of all fidelities; these are "
                                         rf"{JOINT_FIDELITY_RUN_LIMIT + 1}: use method modular"):
        plan_scalar(many, method="koh_emulator")


def test_the_chains_start_at_stage_ones_levels():
    levels = [{"emulator_mean": 0.1, "emulator_sd": 1.2, "emulator_length_scale": [0.4, 0.9], "emulator_nugget": 1e-7,
               "rho": 1.0},
              {"emulator_mean": -0.2, "emulator_sd": 0.3, "emulator_length_scale": [0.5, 0.6],
               "emulator_nugget": 0.01, "rho": 0.9}]
    start = fidelity_emulator_inits({"levels": levels})
    assert start["emulator_sd"] == 0.3 and start["level_rho"] == [0.9] and start["low_emulator_sd"] == [1.2]
    assert start["low_emulator_length_scale"] == [[0.4, 0.9]] and start["low_emulator_nugget"] == [1e-3]
    assert fidelity_emulator_inits({"emulator_sd": 1.0}) == {}  # one fidelity: no levels, Stan's inits
    stage_one = {"hyperparameters": {"levels": levels}, "level_rho": [0.9], "top_level_variance_factor": 2.5,
                 "top_level_variance_error_ratio": [2.5, 0.1], "stage1": "multi-fidelity: 2 levels, ..."}
    reported = as_chain_starts(stage_one)  # the plug-in's variance factor does not enter the joint fit
    assert "top_level_variance_factor" not in reported and "joint path: 2 levels" in reported["stage1"]


# ---- a calibration with a known truth, against modular on the same data -----------------------

@pytest.mark.slow  # two fits of 4 x (1000 + 1000) draws, about 9 minutes on two shared cores
def test_the_joint_path_recovers_k_and_its_interval_against_modulars(tmp_path):
    """koh_emulator with the 40 cheap and 6 expensive runs of
    tests/test_multifidelity's problem: healthy, k's 90 % interval covering
    the truth, its mean inside modular's interval on the same data. At the
    sampler's seed 11 with 4 x (500 + 1000): joint [1.163, 1.239], modular
    [1.140, 1.288], widths 0.076 and 0.148, ratio 0.51 (docs/multifidelity.md);
    R-hat 1.015 on noise_sd there, so warmup 1000, which left 3 divergences
    of 4,000 at adapt_delta 0.9, so 0.95."""
    data = problem()
    joint = fit(data, method="koh_emulator", discrepancy="none", chains=4, warmup=1000, draws=1000,
                adapt_delta=0.95)
    modular = fit(data, method="modular", discrepancy="none", chains=4, warmup=1000, draws=1000)
    assert_healthy(joint)
    k = {name: r.theta_summary()["k"] for name, r in (("joint", joint), ("modular", modular))}
    assert k["joint"]["q05"] <= K_TRUE <= k["joint"]["q95"], k
    # the two integrate the same runs differently (every level's hyperparameters sampled, the readings
    # informing them too, against stage 1's mode with the top level's variance scaled): not the same
    # interval, but one posterior mean inside the other's 90 % interval
    assert k["modular"]["q05"] <= k["joint"]["mean"] <= k["modular"]["q95"], k
    stancal.write_calibration(joint, tmp_path)
    report = (tmp_path / "report.md").read_text()  # stage 1 started the chains; no plug-in's variance factor
    assert "the joint path" in report and "variance times" not in report
