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
posterior, which on the case study held 85 %. (Kennedy & O'Hagan 2000,
section 3, and Le Gratiet & Garnier 2014, section 3, integrate the mean,
rho and the variance analytically but plug in the correlation lengths,
whose uncertainty is most of the shortfall here.)

modular.stan takes one set of hyperparameters, so the integrated answer is
carried into it as a plug-in whose error is honest on average:

- draws of (rho_K, g_K's hyperparameters) from their posterior given the
  top level's runs and the levels below (the objective stage 1 maximised),
  by a random-walk Metropolis chain started at the mode;
- the plug-in predictor's mean squared error under that posterior at
  points over the input box, E[(f - m_hat)^2] = v_mix + (m_mix - m_hat)^2,
  against the plug-in's own variance (Zimmerman & Cressie 1992 correct an
  analogous, frequentist quantity by a Taylor expansion instead);
- g_K's sd and nugget scaled together until the co-kriging variance's box
  average matches that error (never narrowed: the mode is kept when it is
  already as wide). The factor is measured on the whole top level's
  variance, of which g_K's is most but not all, so one fixed-point step
  rescales g_K by the shortfall left after the first scaling; the
  correlations, and so the mean, stay nearly as they were.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy import linalg

from stancal.numerics.finite_differences import gradient_hessian
from stancal.numerics.multifidelity import Level, level_below, level_objective, predict, rho_design
from stancal.numerics.scalable_emulator import negative_log_posterior, pack, unpack

CHAIN = 12000  # Metropolis steps for the top level's hyperparameters (the factor's Monte Carlo sd: VarianceCorrection)
MIXED = 150  # draws kept, evenly thinned, whose co-kriging predictives are averaged
BATCHES = 10  # batch means of the kept draws, for the factor's Monte Carlo sd (Flegal & Jones 2010)
BOX_POINTS = 256  # points of the unit box at which the errors are averaged


@dataclass
class VarianceCorrection:
    """How far the plug-in top level understates its error, and the levels that do not."""

    factor: float  # the plug-in's mean squared error under the posterior over its variance, box average
    factor_sd: float  # its Monte Carlo sd, by batch means over the chain's kept draws
    applied: float  # the factor applied to g_K's own variance (at least 1; above factor: see the fixed point)
    levels: list[Level]


def top_level_draws(levels: list[Level], rng: np.random.Generator, draws: int = MIXED) -> np.ndarray:
    """Draws of v = (rho_K's coefficients, pack(g_K's hyperparameters)) from the posterior
    stage 1 maximised (rho_K's coefficients flat, g_K with emulator.stan's priors, the
    levels below fixed), by a random-walk Metropolis chain from the mode
    whose proposal is the inverse Hessian there, scaled by 2.38^2 / dim
    (Roberts, Gelman & Gilks 1997), thinned to ``draws``."""
    top = levels[-1]
    below = level_below(levels[:-1], top.xt)
    design = rho_design(top.xt, len(top.rho_slope))
    r = design.shape[1]

    def objective(v):
        return level_objective(v, top.xt, top.y, below, design)

    def energy(v):  # the objective's value alone: the proposal needs no gradient
        return negative_log_posterior(v[r:], top.xt, top.y - design @ v[:r] * below)[0]

    current = np.concatenate([top.rho_coefficients, pack(top.hyperparameters)])
    values, vectors = linalg.eigh(gradient_hessian(lambda v: objective(v)[1], current))
    # a flat direction (a nugget far below the runs' scale) gets a bounded step (curvature at least 0.25),
    # not a singular or endless one
    scale = vectors @ np.diag(1 / np.maximum(values, 0.25)) @ vectors.T * 2.38**2 / len(current)
    steps = rng.multivariate_normal(np.zeros(len(current)), scale, CHAIN)
    uniforms = rng.uniform(size=CHAIN)
    level, chain = energy(current), np.empty((CHAIN, len(current)))
    for i in range(CHAIN):
        proposed = current + steps[i]
        proposed_level = energy(proposed)
        if np.log(uniforms[i]) < level - proposed_level:
            current, level = proposed, proposed_level
        chain[i] = current
    kept = chain[CHAIN // 5:]  # burn-in: the first fifth
    return kept[np.linspace(0, len(kept) - 1, draws).round().astype(int)]


def with_top(levels: list[Level], v: np.ndarray) -> list[Level]:
    """The levels with the top one's rho coefficients and hyperparameters set to v."""
    r = 1 + len(levels[-1].rho_slope)
    return [*levels[:-1], replace(levels[-1], rho=float(v[0]), rho_slope=v[1:r], hyperparameters=unpack(v[r:]))]


def variance_correction(levels: list[Level], seed: int = 0) -> VarianceCorrection:
    """The plug-in top level's mean squared error under its hyperparameters'
    posterior, over its own variance, averaged over the unit box; and the
    levels with g_K's variance scaled until the co-kriging variance matches
    it there (never narrowed)."""
    rng = np.random.default_rng(seed)  # one stream: the chain's steps and uniforms, then the points
    mixed = top_level_draws(levels, rng)
    points = rng.uniform(size=(BOX_POINTS, levels[-1].xt.shape[1]))
    plug_mean, plug_variance = predict(levels, points)
    means, variances = np.array([predict(with_top(levels, row), points) for row in mixed]).transpose(1, 0, 2)
    # each draw's box average of E[(f - m_hat)^2 | draw]; their mean is the mixture's error over the box
    per_draw = (variances + (means - plug_mean) ** 2).mean(1)
    error = per_draw.mean()
    batches = np.array([b.mean() for b in np.array_split(per_draw, BATCHES)])
    factor, factor_sd = error / plug_variance.mean(), batches.std(ddof=1) / np.sqrt(BATCHES) / plug_variance.mean()
    applied = max(1.0, float(factor))
    scaled = with_g_scaled(levels, applied)
    if applied > 1:  # g_K is not the whole variance: one fixed-point step closes the shortfall
        applied *= max(1.0, float(error / predict(scaled, points)[1].mean()))
        scaled = with_g_scaled(levels, applied)
    return VarianceCorrection(float(factor), float(factor_sd), applied, scaled)


def with_g_scaled(levels: list[Level], times: float) -> list[Level]:
    """The levels with g_K's sd and nugget scaled so that its variance is ``times`` as large."""
    h = levels[-1].hyperparameters
    scaled = replace(h, sd=h.sd * np.sqrt(times), nugget=h.nugget * np.sqrt(times))
    return [*levels[:-1], replace(levels[-1], hyperparameters=scaled)]
