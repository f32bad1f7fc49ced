"""Held-out predictive scores of a fit: PSIS-LOO on the exact conditional
log p(y_i | y_-i, parameters), or K-fold cross-validation by refitting. The
gap diagnosis ranks candidates with them, and compare reports them."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.special import logsumexp
from scipy.stats import norm

from .data import CalibrationData
from .gap_location import discrepancy_parts
from .result import CalibrationResult

PARETO_K_LIMIT = 0.7  # above it PSIS-LOO is unreliable (Vehtari et al. 2024)


@dataclass
class Score:
    """Predictive performance and remaining discrepancy of one fit."""

    elpd_i: np.ndarray  # pointwise held-out log predictive density
    heldout_mean: np.ndarray  # held-out predictive mean of each observation
    max_pareto_k: float  # NaN under K-fold
    scheme: str  # "psis-loo" or "kfold"
    discrepancy_rms: np.ndarray  # draws: RMS of the GP discrepancy over the physical points

    @property
    def elpd(self) -> float:
        return float(self.elpd_i.sum())

    @property
    def elpd_se(self) -> float:
        return float(np.sqrt(len(self.elpd_i) * np.var(self.elpd_i)))

    def holdout_rmse(self, y: np.ndarray) -> float:
        return float(np.sqrt(np.mean((y - self.heldout_mean) ** 2)))



def _discrepancy_rms(result: CalibrationResult) -> np.ndarray:
    gp, constant = discrepancy_parts(result)
    return np.sqrt(np.mean((gp + constant[:, None]) ** 2, axis=1))


def psis_score(result: CalibrationResult) -> Score:
    """PSIS-LOO on the exact conditional log p(y_i | y_-i, params), and the
    held-out mean as the importance-weighted E(y_i | y_-i, params)."""
    import arviz_stats as ast

    loo = ast.loo(result.idata, pointwise=True, var_name="y")
    log_w = np.asarray(loo.log_weights.transpose("chain", "draw", "obs")).reshape(-1, loo.n_data_points)
    weights = np.exp(log_w - logsumexp(log_w, axis=0))
    loo_mean = np.asarray(result.idata["at_observations"]["y_loo_mean"])
    loo_mean = loo_mean.reshape(-1, loo_mean.shape[-1])
    return Score(np.asarray(loo.elpd_i), (weights * loo_mean).sum(0),
                 float(np.max(loo.pareto_k)), "psis-loo", _discrepancy_rms(result))


def kfold_score(data: CalibrationData, fit, k: int, seed: int,
                discrepancy_rms: np.ndarray) -> Score:
    """K-fold cross-validation: ``fit(train_data, heldout_points)`` returns a
    result whose predictions are at the held-out points."""
    n = len(data.physical)
    folds = np.random.default_rng(seed).permutation(n) % k
    y = data.physical[data.output].to_numpy()
    elpd, mean = np.zeros(n), np.zeros(n)
    for fold in range(k):
        test = np.flatnonzero(folds == fold)
        train = np.flatnonzero(folds != fold)
        result = fit(data.subset(train), data.source.iloc[test].reset_index(drop=True))
        zeta = np.asarray(result.idata["predictions"]["zeta_new"]).reshape(-1, len(test))
        noise = np.asarray(result.idata["posterior"]["noise_sd"]).reshape(-1, 1)
        elpd[test] = logsumexp(norm.logpdf(y[test], zeta, noise), axis=0) - np.log(len(zeta))
        mean[test] = zeta.mean(0)
    return Score(elpd, mean, float("nan"), "kfold", discrepancy_rms)
