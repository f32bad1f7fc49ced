"""Centred or non-centred: how the latent programs (koh_latent*.stan) sample
their discrepancy GP, chosen from the data before anything compiles.

Papaspiliopoulos, Roberts & Sköld (2007, "A general framework for the
parametrization of hierarchical models") show that the centred form (sample
the GP's values delta) mixes well when the data pin delta, and the
non-centred form (sample z, delta = L z) when they do not; each is a funnel or
a long ridge where the other is not. Betancourt & Girolami (2015,
"Hamiltonian Monte Carlo for hierarchical models") show the same for HMC: the
wrong form shows as transitions at the maximum tree depth or divergences.

The rule: at each point, the likelihood's curvature on the model (link) scale
(the observed information about delta_i) is set against the GP prior's
precision there, 1 / sigma^2 with sigma = DISCREPANCY_PRIOR_SD, the scale of
delta_sd's prior (priors.stan). The data dominate the prior at a point when
their ratio is at least DOMINANCE; the discrepancy is sampled centred when
they dominate at more than half the points, non-centred otherwise. The
information per point, from the data alone:

- poisson, log link: the mean; at the data, the count y_i;
- negative binomial: y phi / (y + phi), phi at its prior's median
  (PHI_PRIOR_MEDIAN): unknown overdispersion caps what a count says;
- binomial, logit link: n p (1 - p), p = (y + 1/2) / (n + 1);
- gaussian, standardised: 1 / sigma_obs^2, sigma_obs at its prior's median
  (NOISE_PRIOR_MEDIAN); a censored point counts as none (its lcdf term says
  at most as much as an exact value, and little in the tail).

DOMINANCE = 10 leaves a margin on the side of non-centred, because the two
mistakes are not alike: non-centred where centred was due costs tree depth
(slow), centred where non-centred was due is a funnel (divergences, bias).
A fit that saturates the tree depth anyway is refitted once the other way
(stancal.fitting.calibrate)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from stancal.problem.codes import Censoring, Likelihood
from stancal.problem.observations import Observations

PARAMETRIZATIONS = ("auto", "centred", "non_centred")
DISCREPANCY_PRIOR_SD = 0.5  # priors.stan discrepancy_sd: half-normal(0, 0.5), model scale
# the median of a half-normal(0, 1): noise_sd (standardised units) and inv_sqrt_phi (priors.stan)
_HALF_NORMAL_MEDIAN = 0.6745
NOISE_PRIOR_MEDIAN = _HALF_NORMAL_MEDIAN
PHI_PRIOR_MEDIAN = 1 / _HALF_NORMAL_MEDIAN**2  # phi = 1 / inv_sqrt_phi^2
DOMINANCE = 10.0  # information / prior precision at which the data dominate a point


@dataclass(frozen=True)
class Choice:
    """A parametrisation and the sentence that says why."""

    parametrization: str
    reason: str


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
        n = np.asarray(observations.trials, dtype=float)
        p = (y + 0.5) / (n + 1)
        return n * p * (1 - p)
    exact = np.asarray(observations.censoring) == Censoring.OBSERVED
    return np.where(exact, 1 / NOISE_PRIOR_MEDIAN**2, 0.0)


def choose_parametrization(observations: Observations) -> Choice:
    """Centred when the data dominate the prior (information / prior precision
    >= DOMINANCE) at more than half the points, else non-centred."""
    ratio = information_per_point(observations) * DISCREPANCY_PRIOR_SD**2
    dominated = float(np.mean(ratio >= DOMINANCE))
    chosen = "centred" if dominated > 0.5 else "non_centred"
    return Choice(chosen, (
        f"{chosen} (chosen from the data): the data's information per point is {np.median(ratio):.3g} times "
        f"the discrepancy prior's precision at the median point and at least {DOMINANCE:g} times at "
        f"{100 * dominated:.0f} % of the points; centred needs more than half"))
