"""A mode's posterior mass by the Laplace approximation: the log density at
the mode, and its curvature there from finite differences of the gradient
(Tierney & Kadane 1986, "Accurate approximations for posterior moments and
marginal densities", JASA 81(393); Gelman et al. 2013, Bayesian Data
Analysis, 3rd ed., §13.3). Where two modes' peaks differ, the lower one may
still hold comparable mass if it is wider; the peak heights alone do not
say so."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from stancal.numerics.finite_differences import STEP, gradient_hessian


def laplace_log_mass(log_density: float, gradient: Callable[[np.ndarray], np.ndarray], at: np.ndarray,
                     step: float = STEP) -> float:
    """log of the mass under the quadratic expansion of the log density at
    the optimum ``at`` (unconstrained scale, so the density includes the
    Jacobian as lp__ does): log p(x*) + ½ gᵀ(−H)⁻¹g + d/2 log 2π −
    ½ log det(−H). The gradient g is zero at an exact optimum; kept, it
    makes the answer the same wherever L-BFGS stopped near the peak (it
    stops on a relative change in the density, not on g). H comes from
    central differences of ``gradient``, symmetrised. NaN where −H is not
    positive definite (a saddle, a ridge flat to the differences, a
    gradient that fails): the peak's height is then all that is known."""
    at = np.asarray(at, dtype=float)
    d = at.size
    hessian = gradient_hessian(gradient, at, step, relative=True)
    if not np.all(np.isfinite(hessian)):
        return float("nan")
    curvatures, axes = np.linalg.eigh(-hessian)
    slope = np.asarray(gradient(at), dtype=float)
    if curvatures.min() <= 0 or not np.all(np.isfinite(slope)):
        return float("nan")
    rise = 0.5 * np.sum((axes.T @ slope) ** 2 / curvatures)  # the peak of the expansion above log_density
    return float(log_density + rise + 0.5 * d * np.log(2 * np.pi) - 0.5 * np.sum(np.log(curvatures)))
