"""Each program recovers a known theta from data of an exact simulator."""

import numpy as np
import pandas as pd
import pytest
from conftest import COOLING, K_TRUE, assert_healthy, cooling_data, fit, newton

# Tolerance for agreement between methods: posterior medians of k within
# 0.004 (2 % of the k box [0.01, 0.2]; the koh 90 % interval is about 0.004
# wide). test_methods_agree_over_noise_seeds (slow) measures the spread of the
# differences over noise seeds; the tolerance is at least 3 times it.
AGREEMENT = 0.004
# the noise sd implied by predict()'s y and zeta bands at a new point, relative to the
# posterior's RMS noise sd: over predict seeds 1-5 at the three points of
# test_predict_at_new_points_matches_the_truth the relative error had mean +0.010, sd 0.019,
# largest 0.042; 0.10 is 5 sd
NOISE_TOLERANCE = 0.10


def k_summary(result):
    return result.theta_summary()["k"]


@pytest.mark.parametrize("name", ["koh_fit", "koh_emulator_fit", "modular_fit"])
def test_truth_inside_90_percent_interval(name, request):
    result = request.getfixturevalue(name)
    k = k_summary(result)
    assert k["q05"] < K_TRUE < k["q95"], k
    assert_healthy(result)


@pytest.mark.parametrize("name", ["koh_emulator_fit", "modular_fit"])
def test_emulator_methods_agree_with_koh(name, request, koh_fit):
    other = request.getfixturevalue(name)
    assert_healthy(other)
    assert_healthy(koh_fit)
    assert abs(k_summary(other)["q50"] - k_summary(koh_fit)["q50"]) < AGREEMENT


def test_plain_parameter_estimation_without_discrepancy(exact_cooling_data):
    result = fit(exact_cooling_data, simulator=COOLING / "simulator.stan", method="koh",
                 discrepancy="none", chains=4)  # 2 x 400 draws: R-hat 1.019 on a fresh module
    # Without a discrepancy this is nonlinear regression: on this dataset least
    # squares gives k = 0.05047 (se 0.00015), 3 se from the truth, so the
    # reference is least squares: posterior median within 0.5 se of it and
    # posterior sd within 30 % of its standard error.
    from scipy import optimize

    d = exact_cooling_data.physical
    t, T0, y = d["t"].to_numpy(), d["T0"].to_numpy(), d["temperature"].to_numpy()
    ls = optimize.least_squares(lambda k: newton(t, T0, k[0]) - y, [0.1])
    se = np.sqrt(np.sum(ls.fun**2) / (len(y) - 1) / (ls.jac.T @ ls.jac)[0, 0])
    k_draws = np.asarray(result.idata["posterior"]["theta"]).ravel()
    assert_healthy(result)
    assert abs(np.median(k_draws) - ls.x[0]) < 0.5 * se
    assert abs(k_draws.std() / se - 1) < 0.3
    assert "delta_sd" not in result.idata["posterior"]
    # noise sd used to make the data is 0.3
    noise = np.asarray(result.idata["posterior"]["noise_sd"])
    assert np.quantile(noise, 0.05) < 0.3 < np.quantile(noise, 0.95)


def test_datatree_groups_and_original_units(koh_fit):
    assert_healthy(koh_fit)
    groups = set(koh_fit.idata.children)
    assert {"posterior", "posterior_predictive", "log_likelihood", "observed_data",
            "sample_stats", "predictions", "prior", "prior_predictive"} <= groups
    assert list(koh_fit.idata["posterior"]["theta"].coords["theta_name"].values) == ["k"]
    # replicated temperatures are on the data's scale (deg C), not standardised
    y_rep = np.asarray(koh_fit.idata["posterior_predictive"]["y"]).mean(axis=(0, 1))
    observed = koh_fit.data.physical["temperature"].to_numpy()
    assert np.sqrt(np.mean((y_rep - observed) ** 2)) < 1.0


def test_prior_draws_follow_the_uniform_prior_on_the_box(koh_fit):
    """The prior_only draws of k against the uniform on [0.01, 0.2] (scipy):
    at the 5, 25, 50, 75 and 95 % levels the draws' quantile within 4 Monte
    Carlo se of the uniform's, the se from that quantile's ESS (arviz_stats)
    by the binomial argument, sqrt(p (1 - p) / ESS) / density. (The prior
    run's own sampler diagnostics are not kept by the library; the draws
    being uniform is the check of that run.)"""
    import arviz_stats
    from scipy.stats import uniform

    prior = koh_fit.idata["prior"]["theta"].sel(theta_name="k")
    draws = np.asarray(prior).ravel()
    reference = uniform(0.01, 0.19)
    for p in (0.05, 0.25, 0.5, 0.75, 0.95):
        ess = float(arviz_stats.ess(np.asarray(prior)[..., None], method="quantile", prob=p).squeeze())
        se = np.sqrt(p * (1 - p) / ess) / reference.pdf(reference.ppf(p))
        assert abs(np.quantile(draws, p) - reference.ppf(p)) < 4 * se, (p, np.quantile(draws, p), ess)


def test_predict_at_new_points_matches_the_truth(koh_fit):
    new = pd.DataFrame({"t": [5.0, 30.0, 55.0], "T0": [70.0, 70.0, 85.0]})
    assert_healthy(koh_fit)
    table = koh_fit.predict(new)
    truth = newton(new.t, new.T0, K_TRUE).to_numpy()
    # within the measurement noise (sd 0.3 deg C) of the truth, and covered by
    # the predictive interval of a new observation
    assert np.all(np.abs(table["zeta_q50"] - truth) < 0.5)
    assert np.all(table["y_q05"] < truth) and np.all(truth < table["y_q95"])
    # f at the new points is the simulator at each posterior draw of k: Newton's law in numpy
    # (1e-6 relative: double precision in both, the inputs unscaled and rescaled once)
    k = koh_fit.theta_draws()["k"].to_numpy()[:, None]
    f = newton(new.t.to_numpy()[None, :], new.T0.to_numpy()[None, :], k)
    np.testing.assert_allclose(table["f_mean"], f.mean(axis=0), rtol=1e-6)
    np.testing.assert_allclose(table["f_q50"], np.median(f, axis=0), rtol=1e-6)
    # a new observation adds the measurement noise to zeta: the noise sd the bands imply (in
    # quadrature, as for normals) against the posterior's root mean square noise sd
    noise = np.asarray(koh_fit.idata["posterior"]["noise_sd"]).ravel()
    implied = np.sqrt((table["y_q95"] - table["y_q05"]) ** 2 - (table["zeta_q95"] - table["zeta_q05"]) ** 2) / 3.29
    assert np.all(np.abs(implied / np.sqrt(np.mean(noise**2)) - 1) < NOISE_TOLERANCE), implied


@pytest.mark.parametrize("name", ["koh_emulator_fit", "modular_fit"])
def test_predict_with_emulator(name, request):
    result = request.getfixturevalue(name)
    assert_healthy(result)
    new = pd.DataFrame({"t": [10.0, 40.0], "T0": [65.0, 80.0]})
    table = result.predict(new)
    truth = newton(new.t, new.T0, K_TRUE).to_numpy()
    assert np.all(np.abs(table["zeta_q50"] - truth) < 1.0)


@pytest.mark.parametrize("name", ["koh_emulator_fit", "modular_fit"])
def test_every_emulator_reports_its_runs_replicates(name, request):
    """Replicated runs are found and reported on every program that emulates
    the runs (docs/noise.md), koh_emulator (no stage 1) as modular: the
    shipped cooling runs repeat no setting."""
    result = request.getfixturevalue(name)
    runs = result.emulator["replicated_runs"]
    assert runs["runs"] == len(result.data.runs) and runs["settings"] == len(result.data.runs)
    assert runs["replicated_settings"] == 0 and runs["pooled_within_replicate_sd"] is None


def test_save_and_load_round_trip(koh_fit, tmp_path):
    path = koh_fit.save(tmp_path / "posterior.nc")
    again = type(koh_fit).load(path)
    pd.testing.assert_frame_equal(again.summary(), koh_fit.summary())
    new = pd.DataFrame({"t": [20.0], "T0": [75.0]})
    a, b = koh_fit.predict(new, seed=3), again.predict(new, seed=3)
    np.testing.assert_allclose(a["f_mean"], b["f_mean"], rtol=1e-8)


def test_modular_reports_emulator_accuracy(modular_fit):
    # no sampling claim: the stage-1 emulator's leave-one-out error is computed before sampling
    emulator = modular_fit.emulator
    # leave-one-out error of the stage-1 emulator, small against the runs' spread
    # (measured: 1.1 deg C against a spread of 17.7 deg C, 60 runs in 3 dimensions)
    assert emulator["loo_rmse"] < 0.1 * emulator["runs_sd"]


@pytest.mark.slow  # 18 fits, about 6 minutes
def test_methods_agree_over_noise_seeds():
    """The spread over noise seeds behind AGREEMENT: the emulator methods'
    medians of k minus koh's, on six datasets."""
    differences = {"koh_emulator": [], "modular": []}
    for seed in range(101, 107):
        data = cooling_data(seed)
        koh_result = fit(data, simulator=COOLING / "simulator.stan", method="koh")
        assert_healthy(koh_result)
        koh = k_summary(koh_result)["q50"]
        for method in differences:
            result = fit(data, method=method)
            assert_healthy(result)
            differences[method].append(k_summary(result)["q50"] - koh)
    for method, values in differences.items():
        values = np.array(values)
        print(f"{method} - koh, median of k over 6 seeds: mean {values.mean():+.5f}, sd {values.std(ddof=1):.5f}")
        assert np.abs(values).max() < AGREEMENT
        assert 3 * values.std(ddof=1) < AGREEMENT


def test_predictions_are_indexed_by_the_prediction_points(koh_fit):
    """ArviZ takes a predictions group's dimension names from pred_dims, not dims."""
    zeta = koh_fit.idata["predictions"]["zeta_new"]
    assert zeta.dims == ("chain", "draw", "new_point")
    assert "t" in koh_fit.idata["predictions_constant_data"]
