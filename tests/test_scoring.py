"""Held-out scores: exact refits replace PSIS where its Pareto k is high."""

import numpy as np
import pandas as pd
import xarray as xr
from scipy import stats
from scipy.stats import norm

import stancal
from stancal.diagnosing.scoring import Score, refit_rows, rescored, unreliable_tests


class Refit:
    """A stand-in for calibrate(): predicts N(1, 1) at the held-out points and
    records which rows it was asked to hold out."""

    def __init__(self):
        self.held_out = []

    def __call__(self, train, heldout):
        self.held_out.append(heldout["x"].tolist())
        zeta = np.ones((1, 50, len(heldout)))
        return type("Result", (), {"idata": xr.DataTree.from_dict({
            "predictions": xr.Dataset({"zeta_new": (("chain", "draw", "new_point"), zeta)}),
            "posterior": xr.Dataset({"noise_sd": (("chain", "draw"), np.ones((1, 50)))})})})()


def test_only_the_observations_with_high_pareto_k_are_refitted():
    x = np.arange(6.0)
    data = stancal.CalibrationData(pd.DataFrame({"x": x, "y": x / 2}), ["x"], "y", {"a": (0.0, 1.0)})
    psis = Score(np.full(6, -9.0), np.zeros(6), np.array([0.2, 0.9, 0.3, 0.5, 0.75, 0.1]), "psis-loo",
                 np.zeros((10, 6)))
    refit = Refit()
    tests = unreliable_tests(psis)
    score = rescored(psis, data, tests, [refit(*refit_rows(data, test)) for test in tests], kfold=False)
    assert refit.held_out == [[1.0], [4.0]]  # one refit per point with k > 0.7, that point alone
    expected = np.full(6, -9.0)
    expected[[1, 4]] = norm.logpdf(x[[1, 4]] / 2, 1, 1)
    np.testing.assert_allclose(score.elpd_i, expected)
    assert score.refits == 2 and score.scheme == "psis-loo+refits"
    np.testing.assert_allclose(score.heldout_mean[[1, 4]], 1.0)


def test_held_out_densities_of_every_observation_model():
    """Observations.log_density (K-fold and refit scores) against scipy, one
    row per likelihood and censoring kind."""
    mean = np.array([[2.0, 5.0, 0.5, 3.0], [4.0, 1.0, 2.5, 0.1]])  # two draws
    x = np.arange(4.0)
    counts = pd.DataFrame({"x": x, "y": [1, 7, 0, 3], "n": [4, 9, 2, 5]})
    theta = {"a": (0.0, 1.0)}
    poisson = stancal.CalibrationData(counts, ["x"], "y", theta, likelihood="poisson").observations
    np.testing.assert_allclose(poisson.log_density(np.arange(4), mean), stats.poisson.logpmf(counts.y, mean))
    negbin = stancal.CalibrationData(counts, ["x"], "y", theta, likelihood="negbinomial").observations
    phi = np.array([[2.0], [9.0]])
    np.testing.assert_allclose(negbin.log_density(np.arange(4), mean, phi=phi),
                               stats.nbinom.logpmf(counts.y, phi, phi / (phi + mean)))
    binomial = stancal.CalibrationData(counts, ["x"], "y", theta, likelihood="binomial",
                                       trials="n").observations
    p = mean / 6
    np.testing.assert_allclose(binomial.log_density(np.arange(4), p), stats.binom.logpmf(counts.y, counts.n, p))
    # gaussian: observed, left-censored (y <= 1), right-censored (y >= 4), interval [0, 2], observed
    censored = pd.DataFrame({"x": np.arange(5.0), "y": [1.5, np.nan, np.nan, np.nan, 0.2],
                             "lo": [np.nan, np.nan, 4.0, 0.0, np.nan], "hi": [np.nan, 1.0, np.nan, 2.0, np.nan]})
    gaussian = stancal.CalibrationData(censored, ["x"], "y", theta, lower="lo", upper="hi").observations
    mean, sd = np.column_stack([mean, [0.0, 1.0]]), np.array([[0.5], [2.0]])
    expected = np.column_stack([norm.logpdf(1.5, mean[:, 0], sd[:, 0]), norm.logcdf(1.0, mean[:, 1], sd[:, 0]),
                                norm.logsf(4.0, mean[:, 2], sd[:, 0]),
                                np.log(norm.cdf(2.0, mean[:, 3], sd[:, 0]) - norm.cdf(0.0, mean[:, 3], sd[:, 0])),
                                norm.logpdf(0.2, mean[:, 4], sd[:, 0])])
    np.testing.assert_allclose(gaussian.log_density(np.arange(5), mean, noise_sd=sd), expected, rtol=1e-10)
