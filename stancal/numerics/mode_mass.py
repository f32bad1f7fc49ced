"""The posterior mass of each theta mode, by bridge sampling.

Chains that settle in different modes say nothing about how much posterior
mass each mode holds: chain counts follow the initial values, and a mode's
mean log density leaves out its volume (log Z_k = E_k[log p] + entropy_k).
For each mode, the normalising constant of the posterior restricted to it is
estimated by bridge sampling (Meng & Wong 1996; Gronau et al. 2017, "A
tutorial on bridge sampling") with a normal proposal fitted to the mode's
draws on the unconstrained scale; the modes' weights are the normalised
masses, with their Monte Carlo error (Fruhwirth-Schnatter 2004)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.special import logsumexp
from scipy.stats import multivariate_normal

BRIDGE_ITERATIONS = 1000
BRIDGE_TOLERANCE = 1e-10


@dataclass(frozen=True)
class ModeMass:
    """log of a mode's unnormalised posterior mass and its standard error
    (the relative error of the mass)."""

    log_mass: float
    log_mass_se: float


def bridge_log_mass(draws: np.ndarray, log_density: Callable[[np.ndarray], np.ndarray],
                    rng: np.random.Generator, effective_draws: float | None = None) -> ModeMass:
    """log of the integral of exp(log_density) around ``draws`` (n, d),
    draws of the density restricted to one mode on the unconstrained scale.
    As Gronau et al. (2017) advise, the first half of the draws fits the
    proposal and the second half bridges, so that the proposal does not
    overfit the draws it is compared with. ``effective_draws``: the draws'
    effective sample size (default n)."""
    fitting, draws = np.array_split(draws, 2)
    n, d = draws.shape
    cov = np.cov(fitting, rowvar=False).reshape(d, d) + 1e-10 * np.eye(d)
    proposal = multivariate_normal(fitting.mean(0), cov)
    proposed = proposal.rvs(size=n, random_state=rng).reshape(n, d)
    # log p - log q at the posterior draws (l1) and at the proposal draws (l2)
    l1 = log_density(draws) - proposal.logpdf(draws)
    l2 = log_density(proposed) - proposal.logpdf(proposed)
    n1 = float(effective_draws / 2 if effective_draws else n)
    s1, s2 = n1 / (n1 + n), n / (n1 + n)
    shift = np.median(l1)  # keeps the exponentials in range
    l1, l2 = l1 - shift, l2 - shift
    log_r = 0.0
    for _ in range(BRIDGE_ITERATIONS):
        numerator = logsumexp(l2 - np.logaddexp(np.log(s1) + l2, np.log(s2) + log_r)) - np.log(n)
        denominator = logsumexp(-np.logaddexp(np.log(s1) + l1, np.log(s2) + log_r)) - np.log(len(l1))
        new = numerator - denominator
        if abs(new - log_r) < BRIDGE_TOLERANCE:
            log_r = new
            break
        log_r = new
    # relative mean-squared error of the estimate (Fruhwirth-Schnatter 2004)
    f1 = np.exp(l2 - log_r - np.logaddexp(np.log(s1) + l2 - log_r, np.log(s2)))
    f2 = np.exp(-np.logaddexp(np.log(s1) + l1 - log_r, np.log(s2)))
    relative_mse = f1.var() / f1.mean() ** 2 / n + f2.var() / f2.mean() ** 2 / n1
    return ModeMass(float(log_r + shift), float(np.sqrt(relative_mse)))


def mode_weights(masses: list[ModeMass], rng: np.random.Generator,
                 samples: int = 4000) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each mode's share of the posterior mass: the estimate and its 90 %
    interval over the Monte Carlo error of the log masses."""
    log_mass = np.array([m.log_mass for m in masses])
    se = np.array([m.log_mass_se for m in masses])
    weights = np.exp(log_mass - logsumexp(log_mass))
    simulated = log_mass + se * rng.standard_normal((samples, len(masses)))
    simulated = np.exp(simulated - logsumexp(simulated, axis=1, keepdims=True))
    return weights, np.quantile(simulated, 0.05, axis=0), np.quantile(simulated, 0.95, axis=0)
