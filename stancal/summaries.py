"""The one way stancal summarises draws: the mean and the 5/50/95 % quantiles."""

from __future__ import annotations

import numpy as np

QUANTILES = (0.05, 0.5, 0.95)


def band(draws: np.ndarray) -> dict[str, np.ndarray]:
    """Mean and quantiles over the first axis (the draws): keys mean, q05, q50, q95."""
    draws = np.asarray(draws, dtype=float)
    out = {"mean": draws.mean(0)}
    for q, value in zip(QUANTILES, np.quantile(draws, QUANTILES, axis=0)):
        out[f"q{round(q * 100):02d}"] = value
    return out
