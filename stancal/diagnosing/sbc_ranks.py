"""Rank statistics of simulation-based calibration (Talts et al. 2018) and
their uniformity test with simultaneous ECDF bands (Säilynoja, Bürkner &
Vehtari 2022, as recommended by Modrák et al. 2023).

A rank is the number of (thinned) posterior draws below the value the data
were simulated from: 0..L with L draws. Under a correct program and sampler
it is uniform. Ties are broken at random (a randomised PIT), so the
fractional ranks u = (rank + V) / (L + 1), V ~ U(0, 1), are exactly uniform
on (0, 1) and one continuous test serves every L.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
from scipy.stats import binom

REFERENCE_SAMPLES = 4000  # uniform samples that calibrate the test's statistic and bands


def rank_of(truth: float, draws: np.ndarray) -> int:
    """How many posterior draws lie below the simulated-from value."""
    return int(np.sum(np.asarray(draws) < truth))


def fractional_ranks(ranks: np.ndarray, draws_per_fit: int, rng: np.random.Generator) -> np.ndarray:
    return (np.asarray(ranks, float) + rng.uniform(size=len(ranks))) / (draws_per_fit + 1)


def _grid(sims: int) -> np.ndarray:
    points = min(sims, 100)
    return np.arange(1, points) / points


def gamma_statistic(u: np.ndarray, grid: np.ndarray) -> float:
    """2 min over the grid of the ECDF's two-sided binomial tail probability
    (small when the ECDF strays from the uniform's anywhere)."""
    return float(gamma_statistics(np.asarray(u)[None, :], grid)[0])


def gamma_statistics(samples: np.ndarray, grid: np.ndarray) -> np.ndarray:
    """gamma_statistic of each row of ``samples`` (rows, sims), with one call
    of the binomial's CDF for all rows: per row it cost two scipy calls, and
    the reference law takes thousands of rows."""
    sims = samples.shape[1]
    counts = np.stack([np.searchsorted(row, grid, side="right") for row in np.sort(samples, axis=1)])
    lower = binom.cdf(counts, sims, grid)
    upper = 1 - binom.cdf(counts - 1, sims, grid)
    return 2 * np.min(np.minimum(lower, upper), axis=1)


@functools.lru_cache(maxsize=8)
def reference_statistics(sims: int, seed: int) -> np.ndarray:
    """The gamma statistic's law under uniform ranks, by simulation: the same
    for every parameter of a run, so computed once per run's size and seed."""
    grid = _grid(sims)
    reference = gamma_statistics(np.random.default_rng(seed).uniform(size=(REFERENCE_SAMPLES, sims)), grid)
    reference.flags.writeable = False  # shared between calls
    return reference


@dataclass
class Uniformity:
    """The test of one parameter's ranks."""

    p_value: float
    grid: np.ndarray  # where the ECDF is evaluated
    ecdf_difference: np.ndarray  # ECDF(grid) - grid
    band: tuple[np.ndarray, np.ndarray]  # simultaneous band of the difference at ``level``
    level: float

    @property
    def rejected(self) -> bool:
        return self.p_value < 1 - self.level


def uniformity(u: np.ndarray, level: float = 0.95, seed: int = 0) -> Uniformity:
    """p-value of the gamma statistic against its law under uniform ranks,
    and the simultaneous band that the ECDF difference leaves with
    probability 1 - level, both by simulation of uniform samples."""
    sims = len(u)
    grid = _grid(sims)
    reference = reference_statistics(sims, seed)
    observed = gamma_statistic(u, grid)
    p_value = float(np.mean(reference <= observed))
    critical = np.quantile(reference, 1 - level)
    low = binom.ppf(critical / 2, sims, grid) / sims - grid
    high = binom.ppf(1 - critical / 2, sims, grid) / sims - grid
    ecdf = np.searchsorted(np.sort(u), grid, side="right") / sims
    return Uniformity(p_value, grid, ecdf - grid, (low, high), level)
