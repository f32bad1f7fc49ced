"""Centred, non-centred or partially non-centred: how the latent programs
(koh_latent*.stan) sample their discrepancy GP, chosen from the data before
anything compiles.

Papaspiliopoulos, Roberts & Sköld (2007, "A general framework for the
parametrization of hierarchical models") show that the centred form (sample
the GP's values delta) mixes well when the data pin delta, and the
non-centred form (sample z, delta = L z) when they do not; each is a funnel or
a long ridge where the other is not. Betancourt & Girolami (2015,
"Hamiltonian Monte Carlo for hierarchical models") show the same for HMC: the
wrong form shows as transitions at the maximum tree depth or divergences.

The rule: where the program offers the partially non-centred form
(Christensen, Roberts & Sköld 2006; koh_latent.stan's latent_partial.stan),
it is chosen when the data dominate the prior's marginal variance,
information * sigma^2 >= DOMINANCE (sigma = DISCREPANCY_PRIOR_SD), at more
than half the points. Otherwise, at each point, the likelihood's curvature
on the model (link) scale (the observed information about delta_i) is set
against the GP prior's precision at that point given the other points,
1 / v_i with v_i = 1 / (K^-1)_ii, the kernel K (with the programs' jitter) at the
hyperparameters' prior medians: sd DISCREPANCY_PRIOR_SD, length scales
INPUT_LENGTH_SCALE (simulator inputs) and COVARIATE_LENGTH_SCALE (priors.stan).
For points far apart against the length scale, v_i = sigma^2 and the
comparison is information against 1 / sigma^2; for close points the GP
already ties delta_i to its neighbours and v_i is far smaller. The data
dominate the prior at a point when information * v_i >= DOMINANCE; the
discrepancy is sampled centred when they dominate at more than half the
points, non-centred otherwise. The information per point, from the data:

- poisson, log link: the mean; at the data, the count y_i;
- negative binomial: y phi / (y + phi), phi at its prior's median
  (PHI_PRIOR_MEDIAN): unknown overdispersion caps what a count says;
- binomial, logit link: n p (1 - p), p = (y + 1/2) / (n + 1);
- gaussian, standardised: 1 / sigma_obs^2, sigma_obs at its prior's median
  (NOISE_PRIOR_MEDIAN); a censored point counts as none (its lcdf term says
  at most as much as an exact value, and little in the tail).

Why the neighbours count (measured, 2 chains x (200 + 200), 30 Poisson counts
of 90 to 9,000 on a 10 x 3 grid, squared exponential kernel): compared with
1 / sigma^2 alone, every point is dominated 20 to 2,000 times over, yet the
centred fit spent 384 of 400 transitions at the maximum tree depth (R-hat 1.6)
and the non-centred one none (mean depth 6). DOMINANCE = 10 leaves a margin
on the side of non-centred, because the two mistakes are not alike:
non-centred where centred was due costs tree depth (slow), centred where
non-centred was due is a funnel (divergences, bias). A fit that saturates
the tree depth anyway is refitted once the other way, non-centred after
partial (stancal.fitting.parametrization_fallback)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.stats import halfnorm

from stancal.numerics.hsgp import LENGTH_SCALE_PRIOR
from stancal.numerics.kernels import ard_cross_cov
from stancal.problem.codes import Censoring, Likelihood
from stancal.problem.observations import Observations

DISCREPANCY_PRIOR_SD = 0.5  # priors.stan discrepancy_sd: half-normal(0, 0.5), model scale
INPUT_LENGTH_SCALE = float(LENGTH_SCALE_PRIOR.median())  # discrepancy_length_scale's inverse gamma(3, 1): 0.374
# the median of a half-normal(0, 1): noise_sd (standardised units) and inv_sqrt_phi (priors.stan)
_HALF_NORMAL_MEDIAN = float(halfnorm.median())
COVARIATE_LENGTH_SCALE = 1 / (2 * _HALF_NORMAL_MEDIAN)  # 1 / the median of covariate_relevance's half-normal(0, 2)
JITTER = 1e-6  # of the prior variance: gp_kernels.stan's add_jitter
NOISE_PRIOR_MEDIAN = _HALF_NORMAL_MEDIAN
PHI_PRIOR_MEDIAN = 1 / _HALF_NORMAL_MEDIAN**2  # phi = 1 / inv_sqrt_phi^2
DOMINANCE = 10.0  # information * the prior's conditional variance at which the data dominate a point


@dataclass(frozen=True)
class Choice:
    """A parametrisation and the sentence that says why."""

    parametrization: str
    reason: str


def _binomial_p(observations: Observations) -> np.ndarray:
    """The success probability at each point, (y + 1/2) / (n + 1): kept off
    0 and 1, so its logit and n p (1 - p) stay finite."""
    y = np.nan_to_num(np.asarray(observations.value, dtype=float))
    return (y + 0.5) / (np.asarray(observations.trials, dtype=float) + 1)


def information_per_point(observations: Observations) -> np.ndarray:
    """The likelihood's curvature about the discrepancy at each point, on the
    model scale (the module's docstring: one formula per likelihood)."""
    y = np.nan_to_num(np.asarray(observations.value, dtype=float))
    kind = observations.likelihood
    if kind is Likelihood.POISSON:
        return y
    if kind is Likelihood.NEGBINOMIAL:
        return y * PHI_PRIOR_MEDIAN / (y + PHI_PRIOR_MEDIAN)
    if kind is Likelihood.BINOMIAL:
        p = _binomial_p(observations)
        return np.asarray(observations.trials, dtype=float) * p * (1 - p)
    exact = np.asarray(observations.censoring) == Censoring.OBSERVED
    return np.where(exact, 1 / NOISE_PRIOR_MEDIAN**2, 0.0)


def model_scale_values(observations: Observations, gaussian: np.ndarray) -> np.ndarray:
    """The data's value at each point on the model (link) scale, where the
    likelihood's normal approximation is centred: log(y + 1/2) for counts,
    the empirical logit log((y + 1/2) / (n - y + 1/2)) for binomial successes;
    for a Gaussian output ``gaussian`` as given, the standardised values with
    0 where censored (the programs' y_real: the information is 0 there,
    information_per_point)."""
    kind = observations.likelihood
    if kind in (Likelihood.POISSON, Likelihood.NEGBINOMIAL):
        return np.log(np.nan_to_num(np.asarray(observations.value, dtype=float)) + 0.5)
    if kind is Likelihood.BINOMIAL:
        p = _binomial_p(observations)
        return np.log(p / (1 - p))  # the empirical logit: 1 - p = (n - y + 1/2) / (n + 1)
    return np.asarray(gaussian, dtype=float)


def prior_conditional_variance(x_delta: np.ndarray, inputs: int, kernel_id: int) -> np.ndarray:
    """v_i = 1 / (K^-1)_ii: the discrepancy prior's variance at each point
    given the others, K at the hyperparameters' prior medians (the first
    ``inputs`` columns of ``x_delta``, on [0, 1], are simulator inputs, the
    rest covariates)."""
    x = np.asarray(x_delta, dtype=float).reshape(len(x_delta), -1)
    length_scale = np.where(np.arange(x.shape[1]) < inputs, INPUT_LENGTH_SCALE, COVARIATE_LENGTH_SCALE)
    K = ard_cross_cov(x, x, kernel_id, DISCREPANCY_PRIOR_SD, length_scale)
    K += JITTER * DISCREPANCY_PRIOR_SD**2 * np.eye(len(x))
    return 1 / np.diag(np.linalg.inv(K))


def choose_parametrization(observations: Observations, x_delta: np.ndarray, inputs: int,
                           kernel_id: int, partial: bool = False) -> Choice:
    """Where the program offers it (``partial``), partially non-centred when
    the data dominate the prior's marginal variance (information times
    DISCREPANCY_PRIOR_SD^2 >= DOMINANCE) at more than half the points; else
    centred when they dominate its conditional variance at more than half the
    points, else non-centred."""
    information = information_per_point(observations)
    if partial:
        marginal = information * DISCREPANCY_PRIOR_SD**2
        share = float(np.mean(marginal >= DOMINANCE))
        if share > 0.5:
            return Choice("partial", (
                f"partial (partially non-centred with the data's information, chosen from the data): the "
                f"data's information per point is at least {DOMINANCE:g} times the discrepancy prior's "
                f"precision 1 / sd^2 at {100 * share:.0f} % of the points (median {np.median(marginal):.3g} "
                f"times), so they pin the discrepancy along its smooth directions but not along the rough ones"))
    ratio = information * prior_conditional_variance(x_delta, inputs, kernel_id)
    dominated = float(np.mean(ratio >= DOMINANCE))
    chosen = "centred" if dominated > 0.5 else "non_centred"
    return Choice(chosen, (
        f"{chosen} (chosen from the data): the data's information per point is {np.median(ratio):.3g} times "
        f"the discrepancy prior's precision there (given the other points) at the median point, and at "
        f"least {DOMINANCE:g} times at {100 * dominated:.0f} % of the points; centred needs more than half"))
