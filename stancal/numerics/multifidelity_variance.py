"""The top level's hyperparameters are uncertain: their uncertainty carried
into the multi-fidelity emulator's predictive variance.

Stage 1 plugs in the mode of rho_K and g_K's hyperparameters
(stancal.numerics.multifidelity), found from the few runs of the calibrated
simulator (15 in three dimensions on the case study). Those runs pin them
loosely, and the mode sits at the small-amplitude end of their posterior:
on case_studies/cooling_fidelity g_K's sd is 0.17 at the mode against a
posterior median of 0.24 (0.53 from 300 runs), and the plug-in's 90 %
band held 60 % of 500 fresh expensive runs. A predictive that treats
estimated covariance parameters as known understates its error
(Zimmerman & Cressie 1992); the Bayesian answer integrates them over their
posterior (Kennedy & O'Hagan 2000, section 3; Le Gratiet & Garnier 2014,
section 3), which on the case study held 85 %.

modular.stan takes one set of hyperparameters, so the integrated answer is
carried into it as a plug-in whose error is honest on average:

- draws of (rho_K, g_K's hyperparameters) from their posterior given the
  top level's runs and the levels below (the objective stage 1 maximised),
  by a random-walk Metropolis chain started at the mode;
- the plug-in predictor's mean squared error under that posterior at
  points over the input box, E[(f - m_hat)^2] = v_mix + (m_mix - m_hat)^2,
  against the plug-in's own variance (Zimmerman & Cressie 1992 correct
  the same quantity by a Taylor expansion instead);
- g_K's sd and nugget scaled together by the square root of that ratio
  (never below 1: the mode is kept when it is already as wide), which
  multiplies the top level's own variance and leaves its correlations, and
  so its mean, nearly as they were.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy import linalg

from stancal.numerics.multifidelity import Level, level_below, level_objective, predict
from stancal.numerics.scalable_emulator import negative_log_posterior, pack, unpack

CHAIN = 12000  # Metropolis steps for the top level's hyperparameters: the factor's Monte Carlo sd about 8 %
MIXED = 150  # draws kept, evenly thinned, whose co-kriging predictives are averaged
BOX_POINTS = 256  # points of the unit box at which the errors are averaged
HESSIAN_STEP = 1e-4  # central differences of the objective's gradient


@dataclass
class VarianceCorrection:
    """How far the plug-in top level understates its error, and the levels that do not."""

    factor: float  # the plug-in's mean squared error under the posterior over its variance, box average
    applied: float  # the factor applied to g_K's variance: max(1, factor)
    levels: list[Level]


def hessian(fun, v: np.ndarray, step: float = HESSIAN_STEP) -> np.ndarray:
    """The Hessian of a function returning (value, gradient), by central differences of the gradient."""
    columns = [(fun(v + step * e)[1] - fun(v - step * e)[1]) / (2 * step) for e in np.eye(len(v))]
    H = np.array(columns)
    return (H + H.T) / 2


def top_level_draws(levels: list[Level], seed: int, draws: int = MIXED) -> np.ndarray:
    """Draws of v = (rho_K, pack(g_K's hyperparameters)) from the posterior
    stage 1 maximised (rho_K flat, g_K with emulator.stan's priors, the
    levels below fixed), by a random-walk Metropolis chain from the mode
    whose proposal is the inverse Hessian there, scaled by 2.38^2 / dim
    (Roberts, Gelman & Gilks 1997), thinned to ``draws``."""
    top = levels[-1]
    below = level_below(levels[:-1], top.xt)

    def objective(v):
        return level_objective(v, top.xt, top.y, below)

    def energy(v):  # the objective's value alone: the proposal needs no gradient
        return negative_log_posterior(v[1:], top.xt, top.y - v[0] * below)[0]

    current = np.concatenate([[top.rho], pack(top.hyperparameters)])
    values, vectors = linalg.eigh(hessian(objective, current))
    # a flat direction (a nugget far below the runs' scale) gets a step of sd 2 on the log scale, not a
    # singular or endless one
    scale = vectors @ np.diag(1 / np.maximum(values, 0.25)) @ vectors.T * 2.38**2 / len(current)
    steps = np.random.default_rng(seed).multivariate_normal(np.zeros(len(current)), scale, CHAIN)
    uniforms = np.random.default_rng(seed + 1).uniform(size=CHAIN)
    level, chain = energy(current), np.empty((CHAIN, len(current)))
    for i in range(CHAIN):
        proposed = current + steps[i]
        proposed_level = energy(proposed)
        if np.log(uniforms[i]) < level - proposed_level:
            current, level = proposed, proposed_level
        chain[i] = current
    kept = chain[CHAIN // 5:]  # the first fifth leaves the mode's neighbourhood
    return kept[np.linspace(0, len(kept) - 1, draws).round().astype(int)]


def with_top(levels: list[Level], v: np.ndarray) -> list[Level]:
    """The levels with the top one's rho and hyperparameters set to v."""
    return [*levels[:-1], replace(levels[-1], rho=float(v[0]), hyperparameters=unpack(v[1:]))]


def variance_correction(levels: list[Level], seed: int = 0) -> VarianceCorrection:
    """The plug-in top level's mean squared error under its hyperparameters'
    posterior, over its own variance, averaged over the unit box; and the
    levels with g_K's variance scaled by it (at least 1)."""
    mixed = top_level_draws(levels, seed)
    points = np.random.default_rng(seed).uniform(size=(BOX_POINTS, levels[-1].xt.shape[1]))
    plug_mean, plug_variance = predict(levels, points)
    means, variances = np.array([predict(with_top(levels, row), points) for row in mixed]).transpose(1, 0, 2)
    error = variances.mean(0) + means.var(0) + (means.mean(0) - plug_mean) ** 2
    factor = float(error.mean() / plug_variance.mean())
    applied = max(1.0, factor)
    h = levels[-1].hyperparameters
    scaled = replace(h, sd=h.sd * np.sqrt(applied), nugget=h.nugget * np.sqrt(applied))
    return VarianceCorrection(factor, applied, [*levels[:-1], replace(levels[-1], hyperparameters=scaled)])
