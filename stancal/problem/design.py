"""Designs for simulator runs (review section 7.1)."""

from __future__ import annotations

from collections.abc import Sequence
from itertools import product

import numpy as np
from scipy.stats import qmc


def latin_hypercube_with_corners(lower: Sequence[float], upper: Sequence[float], runs: int,
                                 seed: int) -> np.ndarray:
    """The box's 2^d corners plus a Latin hypercube for the other runs: the
    corners make the runs span the whole box, so no physical point inside it
    needs the emulator to extrapolate. Returns (runs, d)."""
    corners = np.array(list(product(*zip(lower, upper, strict=True))), dtype=float)
    if runs < len(corners):
        raise ValueError(f"{runs} runs cannot hold the {len(corners)} corners of a {len(lower)}-dimensional box")
    inner = qmc.LatinHypercube(d=len(lower), seed=seed).random(runs - len(corners))
    return np.vstack([corners, qmc.scale(inner, lower, upper)])
