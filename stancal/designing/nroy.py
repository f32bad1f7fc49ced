"""The space not ruled out yet (NROY): its volume fraction of theta's box
and a dense uniform sample of it, even when it is a tiny part of the box.

A plain uniform sample holds about fraction x size points of NROY: none at
all once later waves shrink it below 1 / size. Instead, nested cuts (subset
simulation, Au & Beck 2001, "Estimation of small failure probabilities in
high dimensions by subset simulation", Prob. Eng. Mech. 16): from a uniform
sample, the level c_1 that KEEP of it passes; the passing points, copied and
moved by slice sampling uniformly within {I <= c_1}, make the next sample;
and so on down to the cutoff. The fraction is the product of each level's
share. The moves are hit-and-run slice sampling on the level set's
indicator (Neal 2003, "Slice sampling", Ann. Statist. 31, section 4.2; as
hmer's ``generate_new_design`` samples NROY): a random direction scaled by
the current points' spread, a randomly placed window along it, shrunk
towards the current point until a point inside the level set is drawn. The
window is placed uniformly at random around the current point and clipped
to the box; random placement with shrinkage toward the point keeps the
uniform distribution on the level set invariant. The emulator is cheap, so
thousands of evaluations per level cost seconds.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from stancal.problem.validation import DataError

KEEP = 0.2  # share of each level's sample that passes the next level (Au & Beck's p0 = 0.1 - 0.3)
MAX_LEVELS = 40  # KEEP^40 ~ 1e-28 of the box
MOVES = 3  # slice moves of each copy between levels
FINAL_MOVES = 6  # before the sample is returned
WINDOW = 2.0  # the slice window's width, in units of the points' spread
STALL = 0.01  # a level that falls by less than this share of its distance to the cutoff ends the descent
SHRINKS = 40  # at most: the window halves roughly every time, so 40 leaves 1e-12 of it


class NroyEmpty(DataError):
    """Every theta tried is implausible: the message says how close any came."""


@dataclass
class NroySample:
    theta_unit: np.ndarray  # (points, Q): uniform over NROY, theta's unit cube
    implausibility: np.ndarray  # (points,): each point's (combined) implausibility
    fraction: float  # NROY's share of the box
    fraction_cv: float  # coefficient of variation of ``fraction`` for independent samples (a lower bound)
    levels: list[float]  # the nested cuts' thresholds, ending at the cutoff


def slice_moves(theta: np.ndarray, inside: Callable[[np.ndarray], np.ndarray], spread: np.ndarray,
                moves: int, rng: np.random.Generator) -> np.ndarray:
    """``moves`` hit-and-run slice moves of every row of ``theta`` within
    the set {inside}, in the unit cube."""
    theta = theta.copy()
    for _ in range(moves):
        direction = rng.normal(size=theta.shape) * spread
        with np.errstate(divide="ignore"):  # a zero component bounds nothing along the line
            to_low, to_high = -theta / direction, (1 - theta) / direction
        t_min = np.max(np.where(direction > 0, to_low, np.where(direction < 0, to_high, -np.inf)), axis=1)
        t_max = np.min(np.where(direction > 0, to_high, np.where(direction < 0, to_low, np.inf)), axis=1)
        offset = rng.uniform(size=len(theta))
        left = np.maximum(-offset * WINDOW, t_min)
        right = np.minimum((1 - offset) * WINDOW, t_max)
        pending = np.arange(len(theta))
        for _ in range(SHRINKS):
            t = rng.uniform(left[pending], right[pending])
            proposal = np.clip(theta[pending] + t[:, None] * direction[pending], 0.0, 1.0)
            accepted = inside(proposal)
            theta[pending[accepted]] = proposal[accepted]
            rejected = ~accepted
            below = rejected & (t < 0)
            left[pending[below]] = t[below]
            right[pending[rejected & (t >= 0)]] = t[rejected & (t >= 0)]
            pending = pending[rejected]
            if not len(pending):
                break
    return theta


def resample_move(seeds: np.ndarray, inside: Callable[[np.ndarray], np.ndarray], points: int, moves: int,
                  rng: np.random.Generator) -> np.ndarray:
    """``points`` points uniform in the set, from copies of the seeds (each
    in it) moved apart by slice moves scaled by the seeds' spread."""
    copies = seeds[rng.integers(0, len(seeds), points)]
    spread = np.maximum(seeds.std(axis=0), 1e-4) if len(seeds) > 1 else np.full(seeds.shape[1], 0.05)
    return slice_moves(copies, inside, spread, moves, rng)


def sample_nroy(implausibility: Callable[[np.ndarray], np.ndarray], dimensions: int, cutoff: float,
                points: int, seed: int) -> NroySample:
    """NROY = {theta : implausibility(theta) <= cutoff} in the unit cube of
    ``dimensions``: its fraction by nested cuts and ``points`` points
    uniform in it. Raises NroyEmpty when no theta passes."""
    rng = np.random.default_rng(seed)
    theta = rng.uniform(size=(points, dimensions))
    value = implausibility(theta)
    shares, levels = [], []
    while np.mean(value <= cutoff) < KEEP and len(levels) < MAX_LEVELS:
        level = float(np.quantile(value, KEEP))
        if levels and levels[-1] - level < STALL * (level - cutoff):  # the levels close in on a minimum above
            break  # the cutoff, geometrically: no theta gets near it
        passing = value <= level
        shares.append(float(passing.mean()))
        levels.append(level)
        theta = resample_move(theta[passing], lambda t, c=level: implausibility(t) <= c, points, MOVES, rng)
        value = implausibility(theta)
    inside = value <= cutoff
    if not inside.any():
        raise NroyEmpty(f"every theta is implausible at cutoff {cutoff:g}: the smallest implausibility found is "
                        f"{value.min():.3g}; the simulator cannot reach the data within the stated variances "
                        f"(raise [design] discrepancy_sd or noise_sd, or --cutoff)")
    shares.append(float(inside.mean()))
    levels.append(cutoff)
    theta = resample_move(theta[inside], lambda t: implausibility(t) <= cutoff, points, FINAL_MOVES, rng)
    value = implausibility(theta)
    shares_array = np.array(shares)
    cv = float(np.sqrt(np.sum((1 - shares_array) / (shares_array * points))))
    return NroySample(theta, value, float(np.prod(shares_array)), cv, levels)
