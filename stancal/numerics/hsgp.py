"""The Hilbert-space approximate GP discrepancy (Riutort-Mayol et al. 2023,
"Practical Hilbert space approximate Bayesian Gaussian processes for
probabilistic programming"): the basis a problem gets, the paper's check
that the basis can represent the fitted length scales, and a numpy mirror
of functions/hsgp.stan (for the tests and for the gap's design points)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from itertools import product

import numpy as np
from scipy.special import gammaln
from scipy.stats import invgamma

HALF_RANGE = 0.5  # S: the discrepancy inputs live on the unit cube, centred at 0.5
MIN_BOUNDARY_FACTOR = 1.2  # the paper's smallest useful c
# the paper's rules (section 4.3, fitted to its Figure 8): accurate when
#   c >= BOUNDARY_RULE * l / S  and  m >= BASIS_RULE * c * S / l
BOUNDARY_RULE = {"se": 3.2, "matern52": 4.1}
BASIS_RULE = {"se": 1.75, "matern52": 2.65}
# the length scales a first basis is built for, in fractions of an input's
# range: the discrepancy prior's 5 % quantile and median (inv-gamma(3, 1))
SHORTEST_EXPECTED, TYPICAL_EXPECTED = 0.15, 0.37
# more basis functions than this and a gradient costs as much as a dense GP
# on a few hundred points: the product basis is refused
MAX_BASIS_FUNCTIONS = 1500
# the discrepancy length scale's prior (functions/priors.stan), unit range
LENGTH_SCALE_PRIOR = invgamma(3, scale=1)
# the programs cap a length scale at the longest the basis represents
# (hsgp_weight_sd): a length scale is pressed against that cap
# when the data favour lengths beyond it over lengths below it by a Bayes
# factor above 3 ("positive" evidence, Kass & Raftery 1995). A rule on the
# posterior alone fires on the prior itself (half its mass lies beyond the
# first basis's cap) and refits data that say nothing about the length scale
# with a basis five times larger
PRESSED_BAYES_FACTOR = 3.0


def pressed(fitted: np.ndarray, longest: np.ndarray) -> np.ndarray:
    """Per input: do the draws (draws, inputs) press against the longest length scale?"""
    beyond_prior = LENGTH_SCALE_PRIOR.sf(np.asarray(longest, float))
    beyond = (np.asarray(fitted) > longest).mean(axis=0)
    with np.errstate(divide="ignore"):
        bayes_factor = (beyond / (1 - beyond)) / (beyond_prior / (1 - beyond_prior))
    return bayes_factor > PRESSED_BAYES_FACTOR


class BasisTooLargeError(ValueError):
    """The product basis over the discrepancy's inputs is too large."""


@dataclass(frozen=True)
class HSGPBasis:
    """m basis functions per input (``counts``) on [-c S, c S] about the
    centre of each input's range (``boundary_factors`` c); the basis is
    their product over the inputs."""

    counts: tuple[int, ...]
    boundary_factors: tuple[float, ...]

    @property
    def index(self) -> np.ndarray:
        """(B, D): each basis function's eigenfunction number per input."""
        return np.array(list(product(*(range(1, m + 1) for m in self.counts))), dtype=int)

    @property
    def boundary(self) -> np.ndarray:
        return HALF_RANGE * np.asarray(self.boundary_factors)

    @property
    def size(self) -> int:
        return math.prod(self.counts)

    def stan_data(self) -> dict:
        """B, basis_index and boundary of the programs (functions/hsgp.stan)."""
        return {"B": self.size, "basis_index": self.index, "boundary": self.boundary}

    def shortest_length_scale(self, kernel: str) -> np.ndarray:
        """Per input, the shortest length scale (unit range) the basis represents."""
        return BASIS_RULE[kernel] * self.boundary / np.asarray(self.counts)

    def longest_length_scale(self, kernel: str) -> np.ndarray:
        """Per input, the longest length scale the boundary leaves unshrunk;
        the programs cap the length scale there, because a longer one
        shrinks the approximate GP towards 0 and opens a second way (besides
        a small sd) to a null discrepancy, a ridge the sampler crawls along."""
        return self.boundary / BOUNDARY_RULE[kernel]

    def describe(self) -> str:
        counts = " x ".join(str(m) for m in self.counts)
        factors = ", ".join(f"{c:.2f}" for c in self.boundary_factors)
        return f"{self.size} basis functions ({counts}), boundary factor {factors}"


def basis_for(kernel: str, shortest: np.ndarray, longest: np.ndarray, inputs: list[str]) -> HSGPBasis:
    """The paper's rules for inputs whose length scales (unit range) lie
    between ``shortest`` and ``longest``: c from the longest, m from c and
    the shortest."""
    factors = np.maximum(MIN_BOUNDARY_FACTOR, BOUNDARY_RULE[kernel] * np.asarray(longest) / HALF_RANGE)
    counts = np.ceil(BASIS_RULE[kernel] * factors * HALF_RANGE / np.asarray(shortest)).astype(int)
    chosen = HSGPBasis(tuple(int(m) for m in counts), tuple(round(float(c), 3) for c in factors))
    if chosen.size > MAX_BASIS_FUNCTIONS:
        raise BasisTooLargeError(
            f"the Hilbert-space discrepancy over {len(inputs)} inputs ({', '.join(inputs)}) needs "
            f"{chosen.describe()}, more than {MAX_BASIS_FUNCTIONS}: a product basis grows as m^D. "
            f"Give the discrepancy fewer inputs (leave covariates out, or calibrate on the inputs "
            f"that matter), set basis_functions per input yourself, or calibrate a subsample of "
            f"the points with approximation = 'exact'")
    return chosen


def first_basis(kernel: str, inputs: list[str]) -> HSGPBasis:
    """The basis before any fit: for length scales from the discrepancy
    prior's 5 % quantile to its median (the fit's check refines it)."""
    n = len(inputs)
    return basis_for(kernel, np.full(n, SHORTEST_EXPECTED), np.full(n, TYPICAL_EXPECTED), inputs)


def basis_problems(basis: HSGPBasis, kernel: str, fitted: np.ndarray, inputs: list[str]) -> list[str]:
    """The paper's diagnostic (section 4.3): each input's fitted length scale
    (posterior mean, unit range) against the shortest the basis represents
    (too few basis functions: the discrepancy comes out too smooth) and the
    longest, where the programs cap it (pressed against it: the data want
    a smoother discrepancy than the boundary allows). Empty when
    the basis is adequate. ``fitted``: draws (draws, inputs), unit range."""
    problems = []
    short, long = basis.shortest_length_scale(kernel), basis.longest_length_scale(kernel)
    at_bound = pressed(fitted, long)
    fitted_mean = fitted.mean(axis=0)
    for d, name in enumerate(inputs):
        if fitted_mean[d] < short[d]:
            problems.append(f"discrepancy length scale over {name} is {fitted_mean[d]:.3f} of its range, shorter "
                            f"than the {basis.counts[d]} basis functions represent ({short[d]:.3f})")
        elif at_bound[d]:
            problems.append(f"discrepancy length scale over {name} is {fitted_mean[d]:.3f} of its range, pressed "
                            f"against the longest boundary factor {basis.boundary_factors[d]:.2f} represents "
                            f"({long[d]:.3f})")
    return problems


def refined_basis(kernel: str, basis: HSGPBasis, fitted: np.ndarray, inputs: list[str]) -> HSGPBasis:
    """The basis for the length scales a fit found (the paper's iteration:
    rebuild from the fitted values and fit again). ``fitted``: draws
    (draws, inputs) in unit range. Each input gets the shortest of its
    draws' 5 % quantile and the typical length scale, and twice the longest
    where the draws pressed against it (elsewhere the draws beyond the cap
    are the prior's tail, no reason for a wider boundary)."""
    longest = basis.longest_length_scale(kernel)
    return basis_for(kernel, np.minimum(np.quantile(fitted, 0.05, axis=0), TYPICAL_EXPECTED),
                     np.where(pressed(fitted, longest), 2 * longest, longest), inputs)


def basis(x_unit: np.ndarray, index: np.ndarray, boundary: np.ndarray) -> np.ndarray:
    """hsgp_basis of functions/hsgp.stan: (n, D) unit-cube points -> (n, B)."""
    shifted = np.asarray(x_unit, float)[:, None, :] - HALF_RANGE + boundary  # (n, 1, D)
    values = np.sin(np.pi * index[None, :, :] * shifted / (2 * boundary)) / np.sqrt(boundary)
    return values.prod(axis=2)


def weight_sd(index: np.ndarray, boundary: np.ndarray, kernel: str, marginal_sd: float,
              length_scale: np.ndarray, longest: np.ndarray | float = np.inf) -> np.ndarray:
    """hsgp_weight_sd of functions/hsgp.stan: the sd of each basis weight,
    each length scale capped at ``longest``."""
    length_scale = np.minimum(np.asarray(length_scale, float), longest)
    n_dims = len(boundary)
    scaled_sq = ((length_scale * np.pi / (2 * boundary)) ** 2 * index**2).sum(axis=1)
    log_scale = 2 * np.log(marginal_sd) + np.log(length_scale).sum()
    if kernel == "matern52":
        nu = 2.5
        log_density = (log_scale + n_dims * np.log(2) + 0.5 * n_dims * np.log(np.pi)
                       + gammaln(nu + 0.5 * n_dims) + nu * np.log(2 * nu) - gammaln(nu)
                       - (nu + 0.5 * n_dims) * np.log(2 * nu + scaled_sq))
    else:
        log_density = log_scale + 0.5 * n_dims * np.log(2 * np.pi) - 0.5 * scaled_sq
    return np.exp(0.5 * log_density)
