"""Heteroscedastic noise's log sd GP away from its locations, in numpy: the
measurement noise sd at new points, per posterior draw (docs/noise.md).

The programs sample g, the log noise sd GP (log(sd / noise_sd) = g − mean g
over the settings), at the distinct settings of
the noise inputs only (functions/noise.stan's noise_log_scale_at: squared
exponential kernel, jitter 1e-6 of its variance). At a new point g is the
GP's conditional given those values (Rasmussen & Williams 2006, eq. 2.19),
as in the heteroscedastic GP of Binois, Gramacy & Ludkovski (2018, section
3) and the calibration of Sung, Barber & Walker (2022): its mean, and with a
generator one draw from its pointwise conditional variance (the points'
noise is independent given the sd, so their joint draw is not needed)."""

from __future__ import annotations

import numpy as np

from stancal.numerics.kernels import ard_cross_cov
from stancal.numerics.scalable_emulator import JITTER  # add_jitter: 1e-6 of the GP variance on the diagonal
from stancal.problem.codes import Kernel


def log_scale_at(points: np.ndarray, locations: np.ndarray, log_scale: np.ndarray, gp_sd: np.ndarray,
                 length_scale: np.ndarray, rng: np.random.Generator | None = None) -> np.ndarray:
    """g at ``points`` (P, D; unit scale) per draw, (draws, P), from its draws
    at ``locations`` (L, D): ``log_scale`` (draws, L), the marginal sd
    ``gp_sd`` (draws,) and ``length_scale`` (draws, D), unit scale. Without
    ``rng`` the conditional mean, else one conditional draw."""
    log_scale = np.asarray(log_scale, float).reshape(len(gp_sd), -1)
    length_scale = np.asarray(length_scale, float).reshape(len(gp_sd), -1)
    out = np.empty((len(gp_sd), len(points)))
    for s, (sd, ls, values) in enumerate(zip(np.ravel(gp_sd), length_scale, log_scale, strict=True)):
        cov = ard_cross_cov(locations, locations, Kernel.SE, sd, ls) + JITTER * sd**2 * np.eye(len(locations))
        factor = np.linalg.cholesky(cov)
        cross = ard_cross_cov(points, locations, Kernel.SE, sd, ls)
        whitened = np.linalg.solve(factor, cross.T)  # L^-1 K_lp
        out[s] = whitened.T @ np.linalg.solve(factor, values)
        if rng is not None:
            variance = np.clip(sd**2 - (whitened**2).sum(0), 0.0, None)
            out[s] += np.sqrt(variance) * rng.standard_normal(len(points))
    return out
