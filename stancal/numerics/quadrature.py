"""Nodes and weights for integrals over the simulator-input box (the
observed range of each input): the L2 norms of section 6."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy.stats import qmc

from stancal.problem.data import CalibrationData

GAUSS_LEGENDRE_NODES = 48  # one input: exact for polynomials of degree 95
SOBOL_NODES_PER_INPUT = 64  # more inputs: a scrambled Sobol set (power of two)
MAX_SOBOL_NODES = 512


@dataclass(frozen=True)
class Quadrature:
    """``nodes`` (simulator inputs, original units) and ``weights`` summing
    to 1, so that sum(w * g^2) is the mean square of g over the box."""

    nodes: pd.DataFrame
    weights: np.ndarray

    def mean_square(self, values: np.ndarray) -> np.ndarray:
        """values (..., nodes) -> mean square over the box (...)."""
        return (values**2) @ self.weights


def input_box_quadrature(data: CalibrationData, size: int | None = None, seed: int = 0) -> Quadrature:
    """Gauss-Legendre for one input; a scrambled Sobol design with equal weights for more."""
    if data.covariates:
        raise ValueError(
            "an integral over the input box needs a discrepancy over the simulator inputs only; "
            f"remove the covariates {data.covariates} for this method")
    low = data.physical[data.inputs].min().to_numpy(float)
    high = data.physical[data.inputs].max().to_numpy(float)
    if len(data.inputs) == 1:
        unit, weights = np.polynomial.legendre.leggauss(size or GAUSS_LEGENDRE_NODES)
        unit, weights = (unit[:, None] + 1) / 2, weights / 2
    else:
        n = size or min(SOBOL_NODES_PER_INPUT * len(data.inputs), MAX_SOBOL_NODES)
        unit = qmc.Sobol(len(data.inputs), scramble=True, seed=seed).random_base2(int(np.ceil(np.log2(n))))
        weights = np.full(len(unit), 1 / len(unit))
    nodes = pd.DataFrame(low + unit * (high - low), columns=data.inputs)
    return Quadrature(nodes, weights)
