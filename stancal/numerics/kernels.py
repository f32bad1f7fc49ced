"""The discrepancy kernels of stan_models/functions/gp_kernels.stan in
numpy, for post-processing draws (interpolating delta between points)."""

from __future__ import annotations

import numpy as np

from stancal.problem.codes import Kernel


def ard_cross_cov(x1: np.ndarray, x2: np.ndarray, kernel_id: int, marginal_sd: float,
                  length_scale: np.ndarray) -> np.ndarray:
    """Same as the Stan function: x1 (n1, d), x2 (n2, d) -> (n1, n2)."""
    r2 = (((x1[:, None, :] - x2[None, :, :]) / np.asarray(length_scale)) ** 2).sum(-1)
    if kernel_id == Kernel.MATERN52:
        r = np.sqrt(r2)
        return marginal_sd**2 * (1 + np.sqrt(5) * r + 5 * r2 / 3) * np.exp(-np.sqrt(5) * r)
    return marginal_sd**2 * np.exp(-0.5 * r2)
