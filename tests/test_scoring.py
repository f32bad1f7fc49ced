"""Held-out scores: exact refits replace PSIS where its Pareto k is high."""

import numpy as np
import pandas as pd
import xarray as xr
from scipy.stats import norm

import stancal
from stancal.scoring import Score, refit_unreliable


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
                 np.zeros(10))
    refit = Refit()
    score = refit_unreliable(data, refit, psis)
    assert refit.held_out == [[1.0], [4.0]]  # one refit per point with k > 0.7, that point alone
    expected = np.full(6, -9.0)
    expected[[1, 4]] = norm.logpdf(x[[1, 4]] / 2, 1, 1)
    np.testing.assert_allclose(score.elpd_i, expected)
    assert score.refits == 2 and score.scheme == "psis-loo+refits"
    np.testing.assert_allclose(score.heldout_mean[[1, 4]], 1.0)
