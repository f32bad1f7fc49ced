"""The Hessian of a log density from central differences of its exact
(autodiff) gradient: one function for the Laplace mass of a mode
(stancal.numerics.laplace) and the proposal of the multi-fidelity top
level's hyperparameter chain (stancal.numerics.multifidelity_variance)
(Nocedal & Wright 2006, Numerical Optimization, 2nd ed., section 8.1)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

# the central differences' step: the gradient is exact to rounding, so the step trades rounding
# (~1e-16 / h) against the third derivative's error (~h^2); 1e-4 keeps both near 1e-8 of the curvature
STEP = 1e-4


def gradient_hessian(gradient: Callable[[np.ndarray], np.ndarray], at: np.ndarray, step: float = STEP,
                     relative: bool = False) -> np.ndarray:
    """The symmetrised matrix of second derivatives at ``at``, column j from
    the gradient at ``at`` ± h_j e_j; h_j = step, or step × max(1, |at_j|)
    with ``relative`` (a coordinate far from 1 gets a step of its own size).
    Non-finite entries are kept: the caller decides what a failed gradient means."""
    at = np.asarray(at, dtype=float)
    columns = []
    for j in range(at.size):
        h = step * max(1.0, abs(at[j])) if relative else step
        shift = np.zeros(at.size)
        shift[j] = h
        columns.append((np.asarray(gradient(at + shift), dtype=float)
                        - np.asarray(gradient(at - shift), dtype=float)) / (2 * h))
    hessian = np.column_stack(columns) if columns else np.empty((0, 0))
    return (hessian + hessian.T) / 2
