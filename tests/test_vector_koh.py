"""Vector outputs with a cheap Stan simulator (koh_vector.stan), and the
gap diagnosis of a vector output: the issue's proofs 1 (koh) and 2."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest
from conftest import ROOT, assert_gap_summary_healthy, assert_healthy, case_study_module
from test_vector_outputs import long_experiments

from stancal.problem.vector_data import VectorCalibrationData

CURVES = ROOT / "case_studies" / "cooling_curves"
WIND = ROOT / "case_studies" / "cooling_wind"
THETA = {"k": (0.01, 0.1), "Ta": (15.0, 25.0)}


def _log_likelihood(data: VectorCalibrationData, k: np.ndarray, Ta: np.ndarray) -> np.ndarray:
    """Known noise, no discrepancy: independent normals, in numpy, on a grid of (k, Ta)."""
    p = data.physical
    f = Ta[..., None] + (p["T0"].to_numpy() - Ta[..., None]) * np.exp(-k[..., None] * p["t"].to_numpy())
    return -0.5 * (((p["T"].to_numpy() - f) / p["sd"].to_numpy()) ** 2).sum(-1)


def test_koh_vector_posterior_matches_quadrature():
    """Ragged experiments, known noise, no discrepancy: theta's posterior
    mean within 0.1 sd and its sd within 5 % of a grid quadrature of the
    same density (uniform prior on the box); R-hat <= 1.01. The simulator
    is the draught case study's Newton's law, theta = (k, Ta)."""
    from stancal.fitting.vector_calibrate import calibrate_vector

    data = VectorCalibrationData(long_experiments(1), "exp", ["T0"], "T", "t", THETA, noise_sd="sd")
    result = calibrate_vector(data, simulator=WIND / "simulator.stan", discrepancy="none", chains=4,
                              warmup=500, draws=1000, seed=3)
    assert result.method == "koh_vector"
    assert_healthy(result)
    summary = result.theta_summary()
    # a grid over +-8 posterior sd about the sampler's mean holds all the mass
    axes = [np.linspace(summary[n]["mean"] - 8 * summary[n]["sd"], summary[n]["mean"] + 8 * summary[n]["sd"], 301)
            for n in ("k", "Ta")]
    k, Ta = np.meshgrid(*axes, indexing="ij")
    log_p = _log_likelihood(data, k, Ta)
    weight = np.exp(log_p - log_p.max())
    weight /= weight.sum()
    for name, grid in (("k", k), ("Ta", Ta)):
        mean = (weight * grid).sum()
        sd = np.sqrt((weight * (grid - mean) ** 2).sum())
        print(name, summary[name]["mean"], summary[name]["sd"], mean, sd)
        assert abs(summary[name]["mean"] - mean) <= 0.1 * sd, (name, summary[name], mean, sd)
        assert abs(summary[name]["sd"] / sd - 1) <= 0.05, (name, summary[name], mean, sd)
    # the curves are drawn per experiment along the output index; without a discrepancy zeta is
    # Newton's law at each draw, in numpy, at each experiment's T0 along the stored times
    predictions = result.idata["predictions"]
    assert predictions["zeta"].dims[2:] == ("experiment", "output_point") and "t" in predictions.coords
    theta = result.idata["posterior"]["theta"]
    k, Ta = (np.asarray(theta.sel(theta_name=n)).reshape(-1, 1) for n in ("k", "Ta"))
    t = np.asarray(predictions["t"]).reshape(-1)
    for name in predictions["zeta"].coords["experiment"].values:
        T0 = data.experiments.loc[name, "T0"]
        zeta = np.asarray(predictions["zeta"].sel(experiment=name)).reshape(len(k), -1)
        np.testing.assert_allclose(zeta, Ta + (T0 - Ta) * np.exp(-k * t), rtol=1e-6, err_msg=name)
    # and the pointwise log-likelihood is the normal density of each reading, known sd, in scipy
    from scipy.stats import norm

    p = data.physical
    f = Ta + (p["T0"].to_numpy() - Ta) * np.exp(-k * p["t"].to_numpy())
    log_lik = np.asarray(result.idata["log_likelihood"]["y"]).reshape(len(k), -1)
    np.testing.assert_allclose(log_lik, norm.logpdf(p["T"].to_numpy(), f, p["sd"].to_numpy()), rtol=1e-6)


@pytest.mark.slow  # the default run's 12-minute budget (docs/validation.md)
def test_the_cli_calibrates_the_cooling_curves_by_koh_and_by_modular(tmp_path):
    # health not asserted: 2 x 150 draws check the config contract (files and fields), no statistics
    """The issue's config contract with both a Stan simulator and runs: koh
    by default, modular on request (short runs: the files and fields; the
    statistics are checked above and in the slow coverage study)."""
    from stancal.cli import main
    from stancal.problem.config import load_config

    config = CURVES / "config.toml"
    problem = load_config(config)
    assert isinstance(problem.data, VectorCalibrationData) and problem.data.per_experiment[0].name == "offset"
    for method, program in ((None, "koh_vector"), ("modular", "modular_vector")):
        out = tmp_path / program
        flags = ["--method", method] if method else []
        assert main(["calibrate", str(config), "--out", str(out), "--chains", "2", "--warmup", "150",
                     "--draws", "150", "--seed", "1", *flags]) == 0
        summary = json.loads((out / "summary.json").read_text())
        assert summary["method"] == program and set(summary["theta"]) == {"k", "Ta"}
        assert len(summary["theta_per_experiment"]) == 6
        assert (summary["basis"] is None) == (program == "koh_vector")
        if summary["basis"] is not None:  # the basis's two independent errors, each said, original units
            basis = problem.data.basis  # the config's runs, as the command reduced them
            for error in ("truncation", "interpolation"):
                sd = basis.scale * np.sqrt(getattr(basis, f"{error}_variance"))
                assert summary["basis"][f"{error}_sd"] == pytest.approx(sd), error
                assert f"{error} error sd {sd:.3g}" in (out / "report.md").read_text()
        for name in ("posterior.nc", "summary.csv", "curves.png", "theta.png", "report.md", "report.html"):
            assert (out / name).is_file(), (program, name)
    assert main(["compare", str(config), "--out", str(tmp_path / "compare")]) == 2  # refused by name


def test_held_out_values_are_scored_with_their_own_noise():
    """K-fold and exact refits score a held-out value with its known sd, or
    the fit's noise sd (one, or its experiment's)."""
    import xarray as xr
    from scipy.stats import norm

    physical = long_experiments(1)
    zeta = np.array([[50.0, 40.0], [51.0, 41.0]])  # 2 draws x 2 held-out values
    rows = np.array([0, len(physical) - 1])
    y = physical["T"].to_numpy()[rows]
    known = VectorCalibrationData(physical, "exp", ["T0"], "T", "t", THETA, noise_sd="sd")
    assert np.allclose(known.heldout_log_density(rows, zeta, None), norm.logpdf(y, zeta, 0.3))
    estimated = VectorCalibrationData(physical, "exp", ["T0"], "T", "t", THETA)
    names = list(estimated.experiments.index)
    sd = np.array([[[0.5, 1.0, 1.5, 2.0]], [[0.6, 1.1, 1.6, 2.1]]]).reshape(2, 1, 4)  # draw, chain=1, experiment
    posterior = xr.Dataset({"noise_sd": (("draw", "chain", "experiment"), sd)}, coords={"experiment": names})
    per_experiment = posterior.transpose("chain", "draw", "experiment")
    expected = norm.logpdf(y, zeta, sd[:, 0][:, [names.index(physical.exp.iloc[r]) for r in rows]])
    assert np.allclose(estimated.heldout_log_density(rows, zeta, per_experiment), expected)
    one = xr.Dataset({"noise_sd": (("chain", "draw"), [[0.7, 0.8]])})
    assert np.allclose(estimated.heldout_log_density(rows, zeta, one), norm.logpdf(y, zeta, [[0.7], [0.8]]))


def assert_wind_gap_healthy(gap):
    """The baseline and the draught variant (the claims rest on them); the decoys' trouble reported."""
    assert_gap_summary_healthy(gap, claims=("forced_convection",))


@pytest.fixture(scope="session")
def wind_gap(tmp_path_factory):
    """`stancal gap` on the cooling-in-a-draught case study."""
    from stancal.cli import main

    out = tmp_path_factory.mktemp("wind_gap")
    # 2 x (300 + 500): at 2 x (300 + 300) a fit's R-hat was 1.013
    assert main(["gap", str(WIND / "config.toml"), "--out", str(out), "--chains", "2", "--warmup", "300",
                 "--draws", "500", "--seed", "1"]) == 0
    return json.loads((out / "gap.json").read_text()), out


@pytest.mark.slow  # the default run's 12-minute budget (docs/validation.md)
def test_vector_gap_finds_the_withheld_draught(wind_gap):
    """Proof 2: the forced-convection variant ranks first with shrinkage
    above 0.5; the decoys (humidity, probe depth) stay below 0.2; k's error
    shrinks once the draught is modelled (truth 0.045)."""
    K_TRUE = case_study_module(WIND).K_TRUE  # the case study's own truth

    gap, out = wind_gap
    assert_wind_gap_healthy(gap)
    names = [c["name"] for c in gap["candidates"]]
    assert names[0] == "forced_convection", names
    best = gap["candidates"][0]
    assert best["shrinkage"]["mean"] > 0.5 and best["elpd_diff"] > 2 * best["elpd_diff_se"], best
    for decoy in gap["candidates"][1:]:
        assert decoy["shrinkage"]["mean"] < 0.2, decoy
    before = abs(gap["baseline"]["theta"]["k"]["mean"] - K_TRUE)
    after = abs(best["theta"]["k"]["mean"] - K_TRUE)
    assert after < 0.5 * before, (before, after)
    assert (out / "report.md").is_file() and (out / "baseline" / "curves.png").is_file()


@pytest.mark.slow  # the default run's 12-minute budget (docs/validation.md)
def test_vector_gap_locates_the_draught_along_time_and_wind(wind_gap):
    """Where: the gap depends on wind and time, not on humidity or probe
    depth. Fitted without the draught, k settles between the calm and the
    windy cups' rates, so along the curve the gap has opposite signs for
    calm and windy cups (which the average over wind hides): with the wind
    held high the cups cool faster than simulated (simulator too high),
    with it held low, never so (slower, or within the noise)."""
    gap, _ = wind_gap
    assert_wind_gap_healthy(gap)
    importance = {k: v["mean"] for k, v in gap["where"]["importance"].items()}
    assert min(importance["wind"], importance["t"]) > max(importance["humidity"], importance["depth"]), importance
    held = {c["level"]: c for c in gap["where"]["along_index"] if c["given"] == "wind"}
    assert {r["sign"] for r in held["high"]["regions"]} == {"simulator too high"}, held["high"]
    assert "simulator too high" not in {r["sign"] for r in held["low"]["regions"]}, held["low"]


@pytest.mark.slow
def test_koh_vector_covers_the_cooling_curves_truth():
    """Proof 1 for koh: the shipped cooling curves (six ragged cool-downs,
    a probe offset each, known noise, a GP discrepancy), 4 x (1000 + 1000):
    the 90 % intervals cover k, Ta and every offset; R-hat <= 1.01."""
    from stancal.fitting.vector_calibrate import calibrate_vector
    from stancal.problem.config import load_config

    problem = load_config(CURVES / "config.toml")
    result = calibrate_vector(problem.data, simulator=problem.simulator, chains=4, warmup=1000, draws=1000,
                              seed=2, adapt_delta=0.95)
    assert_healthy(result)
    theta = result.theta_summary()
    for name, truth in (("k", 0.045), ("Ta", 21.3)):
        assert theta[name]["q05"] <= truth <= theta[name]["q95"], (name, theta[name])
    offsets = pd.read_csv(CURVES / "truth_offsets.csv").set_index("cooldown")["offset"]
    draws = result.idata["posterior"]["theta_experiment"].sel(experiment_theta_name="offset")
    for cup, truth in offsets.items():
        low, high = np.quantile(np.asarray(draws.sel(experiment=cup)), [0.05, 0.95])
        assert low <= truth <= high, (cup, truth, low, high)


@pytest.mark.slow
def test_vector_gap_from_runs_finds_the_draught_too(tmp_path):
    """The same diagnosis with the baseline and formula candidates fitted by
    modular (the runs' basis emulator) and the variant by koh: the same
    ranking, shrinkage above 0.5 for the draught and below 0.2 for the
    decoys."""
    from stancal.cli import main

    assert main(["gap", str(WIND / "config.toml"), "--out", str(tmp_path), "--method", "modular",
                 "--chains", "4", "--warmup", "500", "--draws", "500", "--seed", "1"]) == 0
    gap = json.loads((tmp_path / "gap.json").read_text())
    assert_wind_gap_healthy(gap)
    assert gap["baseline"]["method"] == "modular_vector"
    names = [c["name"] for c in gap["candidates"]]
    assert names[0] == "forced_convection", names
    assert gap["candidates"][0]["shrinkage"]["mean"] > 0.5
    assert all(c["shrinkage"]["mean"] < 0.2 for c in gap["candidates"][1:]), gap["candidates"]


def test_prediction_rows_of_an_unknown_experiment_are_named():
    from stancal.problem.options import VectorOptions
    from stancal.stan.vector_standata import koh_vector_data

    data = VectorCalibrationData(long_experiments(1), "exp", ["T0"], "T", "t", THETA, noise_sd="sd")
    rows = pd.DataFrame({"exp": ["shot0", "nope"], "T0": [70.0, 70.0], "t": [1.0, 2.0]})
    with pytest.raises(ValueError, match=r"experiment\(s\) \['nope'\] are not in the physical data"):
        koh_vector_data(data, VectorOptions("gp", "known"), None, rows)
