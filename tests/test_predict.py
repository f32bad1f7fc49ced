"""predict() at new points carries the GP's full spread (issue 12, item 1),
and a user's edited program flows through calibrate, summary, predict, save
and load (item 2)."""

import numpy as np
import pandas as pd
import pytest
from conftest import COOLING, K_TRUE, ROOT, assert_healthy, fit

# With 2 x 400 draws the Monte Carlo error of a 90 % band's width is a few
# per cent per point; averaged over the points it is well under 10 %.
BAND_TOLERANCE = 0.10


def band_width(table: pd.DataFrame, name: str) -> np.ndarray:
    return (table[f"{name}_q95"] - table[f"{name}_q05"]).to_numpy()


def stored_points(result) -> pd.DataFrame:
    return result.idata["predictions_constant_data"].to_dataset().to_dataframe().reset_index(drop=True)


@pytest.mark.parametrize("name", ["koh_fit", "koh_emulator_fit", "modular_fit"])
def test_bands_at_the_fitted_points_match_those_stored_at_fit_time(name, request):
    result = request.getfixturevalue(name)
    assert_healthy(result)
    stored = result.predict()  # drawn by the sampler's own RNG
    again = result.predict(stored_points(result), seed=2)
    for quantity in ("zeta", "delta"):
        ratio = band_width(again, quantity) / band_width(stored, quantity)
        assert abs(ratio.mean() - 1) < BAND_TOLERANCE, (quantity, ratio.mean())


@pytest.mark.parametrize("name", ["koh_fit", "modular_fit"])
def test_delta_far_from_the_data_has_its_prior_band(name, request):
    result = request.getfixturevalue(name)
    assert_healthy(result)
    # 40 input ranges away from every physical point: the data say nothing there
    far = pd.DataFrame({"t": [2400.0], "T0": [60.0]})
    table = result.predict(far, seed=3)
    delta_sd = np.asarray(result.idata["posterior"]["delta_sd"]).ravel()
    prior = delta_sd[:, None] * np.random.default_rng(0).standard_normal((delta_sd.size, 200))
    prior_width = np.diff(np.quantile(prior, [0.05, 0.95]))[0]
    assert band_width(table, "delta")[0] / prior_width == pytest.approx(1, abs=BAND_TOLERANCE)


def edited_koh(folder):
    """A user's copy of koh.stan with its own parameter: a separate noise sd
    for the hot starts (T0 > 75 deg C)."""
    code = (ROOT / "stan_models" / "koh.stan").read_text()
    edits = [
        ("  vector[H] beta;                                        // mean-term coefficients, standardised units\n",
         ("  vector[H] beta;                                        // mean-term coefficients, standardised units\n"
         "  real<lower=0> noise_sd_hot;                            // noise sd of the hot starts, standardised\n")),
        ("  beta ~ normal(0, beta_prior_sd);\n",
         "  beta ~ normal(0, beta_prior_sd);\n  noise_sd_hot ~ normal(0, 1);\n"),
        (("    vector[N] noise_var = row_noise_variance(noise_sd, source, known_sd, noise_log_scale, noise_loc);\n"
         "    if (gp_integrated) {\n"),
         ("    vector[N] noise_var = row_noise_variance(noise_sd, source, known_sd, noise_log_scale, noise_loc);\n"
          "    for (i in 1:N) if (X[i, 2] > 75) noise_var[i] = square(noise_sd_hot);\n    if (gp_integrated) {\n")),
    ]
    for old, new in edits:
        assert code.count(old) == 1, old
        code = code.replace(old, new)
    path = folder / "my_koh.stan"
    path.write_text(code)
    return path


@pytest.fixture(scope="module")
def edited_fit(exact_cooling_data, tmp_path_factory):
    program = edited_koh(tmp_path_factory.mktemp("edited"))
    # 2 x 400 draws left R-hat 1.013 on delta_sd once koh.stan took the noise models (the same density)
    return fit(exact_cooling_data, simulator=COOLING / "simulator.stan", method="koh", program=program, draws=800)


def test_an_edited_program_with_its_own_parameter_works_end_to_end(edited_fit, tmp_path):
    assert_healthy(edited_fit)
    summary = edited_fit.summary()
    assert "noise_sd_hot" in summary.index
    # both noise sds made the data: 0.3 deg C, here in the program's standardised units
    hot = np.asarray(edited_fit.idata["posterior"]["noise_sd_hot"]).ravel() * edited_fit.data.scaling.y_scale
    assert np.quantile(hot, 0.05) < 0.3 < np.quantile(hot, 0.95)
    k = edited_fit.theta_summary()["k"]
    assert k["q05"] < K_TRUE < k["q95"]
    new = pd.DataFrame({"t": [10.0, 40.0], "T0": [65.0, 85.0]})
    table = edited_fit.predict(new)
    assert np.all(np.isfinite(table["zeta_q50"]))
    again = type(edited_fit).load(edited_fit.save(tmp_path / "posterior.nc"))
    pd.testing.assert_frame_equal(again.summary(), summary)
    np.testing.assert_allclose(again.predict(new, seed=4)["f_mean"], edited_fit.predict(new, seed=4)["f_mean"])
