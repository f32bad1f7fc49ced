"""The next simulator runs, two ways.

- ``nroy`` (default): space-filling within NROY x the physical inputs' range:
  greedy maximin selection (Johnson, Moore & Ylvisaker 1990, "Minimax and
  maximin distance designs", J. Stat. Plan. Inference 26) from candidates
  that pair the NROY sample's theta with a Latin hypercube of the inputs;
  each pick is the candidate farthest, on the unit cube of (x, theta), from
  every existing run and every earlier pick.
- ``posterior``: the batch that most reduces the emulator's variance where
  calibration uses it, at the data's inputs and theta's posterior: the
  posterior-weighted integrated variance of Koerner et al. (2023, the IMSPE
  of the KOH emulator; weighted by theta's posterior, as Sürer et al. 2023's
  EIVAR weights by it), sum over reference points r = (x_i, theta_s) of the
  variance a new run at c removes, cov(r, c)^2 / var(c). A GP's variance does
  not depend on the outputs, so the batch is chosen one run at a time with
  the exact update (what a kriging believer would give for the variance).
"""

from __future__ import annotations

import numpy as np
from scipy.stats import qmc

from stancal.designing.emulators import GaussianProcess, pairs
from stancal.numerics.scalable_emulator import JITTER

CANDIDATES = 4000  # for maximin
POSTERIOR_CANDIDATES = 1500  # for the posterior criterion (a dense candidate-candidate covariance)
REFERENCE_THETA = 60  # posterior draws in the reference points
REFERENCE_POINTS = 60  # observed inputs in them, at most


def candidates(theta_unit: np.ndarray, inputs: int, count: int, rng: np.random.Generator) -> np.ndarray:
    """(count, D + Q): theta from ``theta_unit`` (rows drawn at random), the
    inputs a Latin hypercube of the unit cube."""
    theta = theta_unit[rng.integers(0, len(theta_unit), count)]
    if not inputs:
        return theta
    x = qmc.LatinHypercube(d=inputs, seed=rng).random(count)
    return np.column_stack([x, theta])


def maximin(pool: np.ndarray, existing: np.ndarray, count: int) -> tuple[np.ndarray, np.ndarray]:
    """Indices of ``count`` rows of ``pool``, each the farthest from
    ``existing`` and the rows chosen before it (greedy maximin), and each
    pick's distance to the nearest of those when picked (their minimum is
    the design's smallest distance between any two of its runs)."""
    if count > len(pool):
        raise ValueError(f"{count} runs asked for, from {len(pool)} candidates")
    nearest = np.full(len(pool), np.inf)
    for row in existing:
        nearest = np.minimum(nearest, np.linalg.norm(pool - row, axis=1))
    chosen, distances = [], []
    for _ in range(count):
        best = int(np.argmax(nearest))
        chosen.append(best)
        distances.append(nearest[best])
        nearest = np.minimum(nearest, np.linalg.norm(pool - pool[best], axis=1))
    return np.array(chosen), np.array(distances)


def nroy_runs(theta_unit: np.ndarray, existing: np.ndarray, inputs: int, count: int,
              seed: int) -> tuple[np.ndarray, np.ndarray]:
    """``count`` new runs (count, D + Q), unit cube: maximin over NROY x the
    inputs' box; and each pick's distance to its nearest earlier run (maximin)."""
    pool = candidates(theta_unit, inputs, max(CANDIDATES, 4 * count), np.random.default_rng(seed))
    chosen, distances = maximin(pool, existing, count)
    return pool[chosen], distances


def variance_reduction_batch(parts: list[tuple[GaussianProcess, float]], pool: np.ndarray, references: np.ndarray,
                             count: int) -> tuple[np.ndarray, list[float]]:
    """Indices of ``count`` rows of ``pool`` chosen one at a time, each the
    one whose run most reduces the summed predictive variance at
    ``references`` (each GP weighted by its output variance per unit), and
    each pick's reduction (output units squared, summed over the references).
    A new run carries the GP's nugget (and jitter), as the runs do."""
    states = [(weight, gp.covariance(pool, references), gp.covariance(pool, pool))
              for gp, weight in parts]
    nuggets = [gp.hyperparameters.nugget**2 + JITTER * gp.hyperparameters.sd**2 for gp, _ in parts]
    chosen, gains = [], []
    for _ in range(count):
        score = np.zeros(len(pool))
        for (weight, to_references, among), nugget in zip(states, nuggets, strict=True):
            score += weight * np.sum(to_references**2, axis=1) / (np.maximum(np.diag(among), 0.0) + nugget)
        score[chosen] = -np.inf
        best = int(np.argmax(score))
        chosen.append(best)
        gains.append(float(score[best]))
        for k, (weight, to_references, among) in enumerate(states):
            pivot = max(among[best, best], 0.0) + nuggets[k]
            column = among[:, best].copy()
            states[k] = (weight, to_references - np.outer(column, to_references[best]) / pivot,
                         among - np.outer(column, column) / pivot)
    return np.array(chosen), gains


def posterior_runs(parts: list[tuple[GaussianProcess, float]], posterior_theta: np.ndarray, x_unit: np.ndarray,
                   count: int, seed: int, experiments=()) -> tuple[np.ndarray, list[float]]:
    """``count`` new runs (count, D + Q), unit cube, by the posterior-weighted
    integrated variance: references (x_i, theta_s) at observed inputs and
    posterior draws; candidates pair posterior draws with the observed
    inputs (half) and a Latin hypercube of the inputs' box (half).
    ``experiments``, with per-experiment theta: each experiment's inputs
    (its row of the unit cube) and the columns of ``posterior_theta`` (NROY's
    theta) its runs take, the shared theta and its own (UnitBox.selection)."""
    rng = np.random.default_rng(seed)
    inputs = x_unit.shape[1]
    draws = posterior_theta[rng.choice(len(posterior_theta), min(REFERENCE_THETA, len(posterior_theta)),
                                       replace=False)]
    if experiments:
        references, pool = per_experiment_points(experiments, posterior_theta, draws, inputs, rng)
        chosen, gains = variance_reduction_batch(parts, pool, references, count)
        return pool[chosen], gains
    unique_x = np.unique(x_unit, axis=0) if inputs else np.zeros((1, 0))
    xs = unique_x[rng.choice(len(unique_x), min(REFERENCE_POINTS, len(unique_x)), replace=False)]
    references = pairs(xs, draws)
    pool = candidates(posterior_theta, inputs, POSTERIOR_CANDIDATES, rng)
    if inputs:
        half = POSTERIOR_CANDIDATES // 2
        pool[:half, :inputs] = unique_x[rng.integers(0, len(unique_x), half)]
    chosen, gains = variance_reduction_batch(parts, pool, references, count)
    return pool[chosen], gains


def per_experiment_points(experiments, posterior_theta: np.ndarray, draws: np.ndarray, inputs: int,
                          rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """The posterior criterion's references and candidates with per-experiment
    theta, where calibration uses the emulator: experiment e's inputs at
    each draw's shared theta and e's own (at most REFERENCE_POINTS
    experiments); candidates take a random draw's shared theta and a random
    experiment's own, with that experiment's inputs (half) or a Latin
    hypercube's (half)."""
    rows = np.array([row for row, _ in experiments]).reshape(len(experiments), inputs)
    columns = np.array([c for _, c in experiments])
    kept = rng.choice(len(experiments), min(REFERENCE_POINTS, len(experiments)), replace=False)
    references = np.vstack([pairs(rows[e][None, :], draws[:, columns[e]]) for e in kept])
    which = rng.integers(0, len(experiments), POSTERIOR_CANDIDATES)
    theta = np.take_along_axis(posterior_theta[rng.integers(0, len(posterior_theta), POSTERIOR_CANDIDATES)],
                               columns[which], axis=1)
    x = qmc.LatinHypercube(d=inputs, seed=rng).random(POSTERIOR_CANDIDATES) if inputs \
        else np.zeros((POSTERIOR_CANDIDATES, 0))
    half = POSTERIOR_CANDIDATES // 2
    x[:half] = rows[which[:half]]
    return references, np.column_stack([x, theta])
