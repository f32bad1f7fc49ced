"""Simulation-based calibration of a vector output (Talts et al. 2018;
Modrák et al. 2023): the replicated readings the prior run simulates have
modular_vector.stan's law at each draw's parameters (numpy), a tiny SBC runs
end to end and writes its ranks, a program SBC does not take is refused
before anything compiles, and (slow) a deliberately wrong program is caught.

The design is tests/test_vector_multifidelity's cooling curves, shrunk: three
cool-downs of eight readings (known sd 0.4 deg C) and 8 expensive runs."""

from __future__ import annotations

import json
import re
import shutil

import numpy as np
import pytest
from conftest import ROOT, no_stancal_warnings
from test_vector_multifidelity import problem
from test_vector_outputs import moments_reference

from stancal.problem.data import bounds_of
from stancal.problem.vector_data import VectorCalibrationData


def design(runs: int = 8) -> VectorCalibrationData:
    """The cooling curves with the expensive runs alone (no cheaper ones)."""
    return problem(low=0, high=runs)


def discrepancy_cov(stan_data: dict, sd: float, length_scale: np.ndarray) -> np.ndarray:
    """The discrepancy's squared-exponential covariance over (inputs, output
    index) at the measured values, standardised units (no covariates)."""
    experiment = np.asarray(stan_data["experiment"]) - 1
    points = np.column_stack([np.asarray(stan_data["x"]).reshape(stan_data["E"], -1)[experiment],
                              np.asarray(stan_data["index"]).reshape(stan_data["N"], -1)])
    scaled = points / np.asarray(length_scale)
    squared = ((scaled[:, None, :] - scaled[None, :, :]) ** 2).sum(-1)
    return sd ** 2 * np.exp(-0.5 * squared)


def test_the_prior_runs_readings_have_the_programs_law_at_each_draw():
    """The prior run SBC draws its data sets from (calibrate_vector with
    prior=True, modular with a discrepancy): at each prior draw's own
    parameters, its replicated readings y_rep are normal with numpy's mean
    and covariance (the emulator's weights at theta, the basis' truncation,
    the known noise, the discrepancy's GP). Whitened by numpy's Cholesky
    factor at its draw, every draw's 24 values are iid N(0, 1) if and only if
    the law is right: over 400 draws their means are 0 within 4.5 standard
    errors (1 / sqrt(400)) and their covariance is the identity within 4.5
    standard errors of a sample covariance (sqrt(2 / 400) = 0.071 on the
    diagonal; 300 distinct entries, so a false alarm at that width has odds
    about 0.2 %). A variance off by 35 % (an sd by 16 %) moves the diagonal
    by 0.35, beyond the 0.32 allowed."""
    from stancal.fitting.vector_calibrate import calibrate_vector, prediction_rows
    from stancal.stan.vector_standata import build_vector_stan_data

    data = design()
    assert data.with_output(data.physical[data.output].to_numpy()).physical.equals(data.physical)
    # health not asserted: one short chain of the posterior, read only for its prior groups (as SBC's prior run)
    with no_stancal_warnings(allow="R-hat|effective sample size"):
        # one prediction row per experiment: the predictions are not read here
        fit = calibrate_vector(data, method="modular", discrepancy="gp", chains=1, warmup=100, draws=400, seed=4,
                               prior=True, new_rows=prediction_rows(data, 1))
    stan_data = build_vector_stan_data(data, fit.row.data, fit.options, prediction_rows(data, 1), fit.emulator)
    parameters = fit.idata["prior_stan_parameters"]
    replicated = np.asarray(fit.idata["prior_predictive"]["y"]).reshape(-1, len(data.physical))
    theta = np.asarray(parameters["theta_unit"]).reshape(len(replicated), -1)
    delta_sd = np.asarray(parameters["delta_sd"]).reshape(-1)
    length_scale = np.asarray(parameters["delta_input_length_scale"]).reshape(len(replicated), -1)
    standardised = (replicated - np.asarray(stan_data["output_mean"])) / stan_data["output_scale"]
    whitened = []
    for s in range(len(replicated)):
        mu, K = moments_reference(stan_data, fit.emulator, theta[s])
        L = np.linalg.cholesky(K + discrepancy_cov(stan_data, delta_sd[s], length_scale[s]))
        whitened.append(np.linalg.solve(L, standardised[s] - mu))
    z = np.asarray(whitened)
    n = len(z)
    assert np.abs(z.mean(0)).max() < 4.5 / np.sqrt(n), z.mean(0)
    covariance = np.cov(z, rowvar=False)
    assert np.abs(np.diag(covariance) - 1).max() < 4.5 * np.sqrt(2 / n), np.diag(covariance)
    off = covariance[~np.eye(len(covariance), dtype=bool)]
    assert np.abs(off).max() < 4.5 / np.sqrt(n), np.abs(off).max()


def test_a_tiny_vector_sbc_writes_its_ranks_and_reuses_stage_one(tmp_path, monkeypatch):
    """Two simulations end to end on the vector design: one rank per
    simulation for theta, the discrepancy's hyperparameters and the
    log-likelihood, each the count of its thinned draws below the truth
    (truth.json, ranked_draws.json); stage 1 runs once, for the prior; a
    rerun into the same folder reuses the finished simulations, and so
    does a subset of them."""
    import stancal.diagnosing.sbc as sbc
    import stancal.fitting.vector_calibrate as vector_module
    from stancal.diagnosing.sbc import RANKED_DRAWS, SBC_WARMUP, TRUTH, simulation_based_calibration

    ran, calls, warmups = [], [], set()

    def counted(*args, **kwargs):
        ran.append(kwargs["seed"])
        return run_stage_one(*args, **kwargs)

    def called(*args, **kwargs):
        calls.append("prior" if kwargs.get("prior") else "fit")
        warmups.add((calls[-1], kwargs["warmup"]))
        return calibrate_vector(*args, **kwargs)

    run_stage_one, calibrate_vector = vector_module.run_stage_one, sbc.calibrate_vector
    monkeypatch.setattr(vector_module, "run_stage_one", counted)
    monkeypatch.setattr(sbc, "calibrate_vector", called)
    short_fits = "R-hat|effective sample size|beyond the simulator runs"
    settings = {"method": "modular", "discrepancy": "gp", "simulations": 2, "draws_per_fit": 10, "chains": 1,
                "warmup": 100, "seed": 3, "scheduler": "in-process", "out_dir": tmp_path}
    # health is not asserted per fit: only ranks travel back from SBC's fits (as test_sbc's study); fits
    # this short mix poorly, and say so; a truth drawn from theta's prior may lie beyond the runs, and its fit
    # says so
    with no_stancal_warnings(allow=short_fits):
        result = simulation_based_calibration(design(), **settings)
        again = simulation_based_calibration(design(), **settings)  # all finished: the prior run alone
    assert len(ran) == 2 and not result.failed  # one stage 1 per SBC, its prior run's
    assert again.ranks == result.ranks and calls == ["prior", "fit", "fit", "prior"]  # no fit ran again
    names = {"theta[k]", "delta_sd", "delta_length_scale[T0]", "delta_length_scale[t]", "log_likelihood"}
    assert set(result.ranks) == names and all(len(r) == 2 for r in result.ranks.values())
    # each fit's sampler checks travel back with its ranks and are summed up (tests/test_sbc_health.py)
    assert result.fits_health["fits"] == 2 and result.fits_health["fit_draws"] == 20  # 1 chain x 2 x 10
    assert json.loads((tmp_path / "sbc.json").read_text())["fits_health"] == result.fits_health
    saved = json.loads((tmp_path / "sbc.json").read_text())["parameters"]
    for s in range(2):
        folder = tmp_path / "fits" / f"{s:04d}"
        truth = json.loads((folder / TRUTH).read_text())["values"]
        draws = json.loads((folder / RANKED_DRAWS).read_text())
        for name in names:
            assert len(draws[name]) == 10
            assert saved[name]["ranks"][s] == result.ranks[name][s] == int(np.sum(np.asarray(draws[name])
                                                                                  < truth[name]))
    # a subset of the simulations (to refit some with longer chains) is fitted as in the whole run: the same
    # fingerprint, so here reused; a simulation that is not in the run is refused before the prior run
    with pytest.raises(ValueError, match=r"subset must list distinct simulations from 0 to 1; got \[2\]"):
        simulation_based_calibration(design(), **settings, subset=[2])
    with no_stancal_warnings(allow=short_fits):
        part = simulation_based_calibration(design(), **settings, subset=[1, 0])
    assert calls[4:] == ["prior"] and part.simulations == 2 and not part.failed
    assert part.ranks == {name: [ranks[1], ranks[0]] for name, ranks in result.ranks.items()}
    with pytest.raises(ValueError, match=r"SBC's rank test needs at least 2 simulations; got 1 \(2 simulations, "
                                         r"subset \[0\]\)"):
        simulation_based_calibration(design(), **settings, subset=[0])
    assert len(calls) == 5
    # the prior run's warm-up is SBC's own, not the fits': longer fits (to tell the sampler from the model)
    # refit the very simulations of a run with the default fits
    assert warmups == {("prior", SBC_WARMUP), ("fit", 100)}


def test_a_program_sbc_does_not_take_is_refused_before_anything_compiles(tmp_path, monkeypatch, capsys):
    """koh_emulator for a vector output (its weight GPs sampled with theta)
    has no SBC yet: one line naming the program and what SBC takes, before
    the prior run and before the output folder is written; `stancal sbc` on
    the cooling curves' config with that method says the same."""
    import stancal.diagnosing.sbc as sbc
    from stancal.cli import main

    def never(*args, **kwargs):
        raise AssertionError("the prior run started")

    monkeypatch.setattr(sbc, "calibrate_vector", never)
    taken = r"does not take program 'koh_emulator_vector' yet; for a vector output it takes koh_vector, modular_vector"
    with pytest.raises(ValueError, match=taken):
        sbc.simulation_based_calibration(design(), method="koh_emulator", simulations=4, out_dir=tmp_path / "out")
    assert not (tmp_path / "out").exists()
    case = shutil.copytree(ROOT / "case_studies" / "cooling_curves", tmp_path / "case")
    config = case / "config.toml"
    assert config.read_text().count("[model]\n") == 1
    config.write_text(config.read_text().replace("[model]\n", '[model]\nmethod = "koh_emulator"\n'))
    assert main(["sbc", str(config), "--out", str(tmp_path / "out")]) == 2
    assert re.search(taken, capsys.readouterr().err.strip().splitlines()[-1])
    assert not (tmp_path / "out").exists()


@pytest.mark.slow
def test_vector_sbc_flags_a_likelihood_with_the_wrong_noise_scale(tmp_path):
    """The vector design with one noise sd estimated and no discrepancy, 40
    simulations: fitted by a copy of modular_vector.stan whose likelihood
    doubles the noise sd (its variance times 4), noise_sd's ranks and the
    log-likelihood's are not uniform. The same simulations fitted by the
    program itself are the benchmark's study (benchmarks/sbc_families.py,
    docs/validation.md), too long for a test."""
    from stancal.diagnosing.sbc import simulation_based_calibration
    from stancal.stan.source import shipped_models_dir

    source = (shipped_models_dir() / "modular_vector.stan").read_text()
    right = "independent_variance(noise_mode, known_noise_sd, noise_sd, experiment)"
    assert source.count(right) == 2  # the model block's, then generated quantities' (log_lik stays right)
    wrong = tmp_path / "modular_vector_wrong_noise.stan"
    wrong.write_text(source.replace(right, f"4 * {right}", 1))
    # health is not asserted per fit: only ranks travel back from SBC's fits (as test_sbc's study)
    data = design()
    data = VectorCalibrationData(data.source, data.experiment, data.inputs, data.output, data.output_index,
                                 bounds_of(data.parameters), runs=data.runs, run=data.run)  # the sd estimated
    with no_stancal_warnings(allow="R-hat|effective sample size|diverge|tree depth"):
        bad = simulation_based_calibration(data, method="modular", discrepancy="none", program=wrong,
                                           simulations=40, draws_per_fit=30, chains=1, warmup=150, seed=5)
    print({n: round(t.p_value, 4) for n, t in bad.tests.items()})
    assert bad.tests["noise_sd"].rejected and bad.tests["log_likelihood"].rejected


def test_the_vector_log_likelihood_at_given_parameters_matches_numpy():
    """SBC ranks the log-likelihood at the true parameters among its values
    at the posterior draws. For koh_vector (cooling_wind's Newton's law in
    Stan, known noise, no discrepancy), at one posterior draw's own Stan
    parameters it equals the sampler's log_lik there and the normal density
    of the residuals in numpy (original units)."""
    from scipy.stats import norm
    from test_vector_koh import THETA, WIND
    from test_vector_outputs import cooling, long_experiments

    from stancal.diagnosing.sbc import log_likelihood_at, log_likelihood_draws
    from stancal.fitting.vector_calibrate import calibrate_vector

    data = VectorCalibrationData(long_experiments(1), "exp", ["T0"], "T", "t", THETA, noise_sd="sd")
    # health not asserted: 20 draws, read only as parameter values at which two log-likelihoods are compared
    with no_stancal_warnings(allow="R-hat|effective sample size"):  # 20 draws: they say so
        fit = calibrate_vector(data, simulator=WIND / "simulator.stan", discrepancy="none", chains=1, warmup=150,
                               draws=20, seed=2)
    draw = 7
    parameters = {k: np.asarray(v)[0, draw] for k, v in fit.idata["stan_parameters"].data_vars.items()}
    at_draw = log_likelihood_at(fit, parameters)
    assert at_draw == pytest.approx(log_likelihood_draws(fit)[draw], rel=1e-10)
    k, Ta = np.asarray(fit.idata["posterior"]["theta"])[0, draw]
    p = data.physical
    expected = norm.logpdf(p["T"], cooling(p["t"], p["T0"], k, Ta), p["sd"]).sum()
    assert at_draw == pytest.approx(expected, rel=1e-8)
