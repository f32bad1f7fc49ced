"""The multi-fidelity emulator: the autoregressive model of Kennedy &
O'Hagan (2000) for simulators of K levels of fidelity, cheapest first,

    f_1(t) = g_1(t),    f_k(t) = rho_k f_{k-1}(t) + g_k(t)   (k = 2..K),

with independent GPs g_k over t = (x, theta) (squared exponential, the
kernel of stage 1) and constant scales rho_k (review section 8.3; Goh et
al. 2013 use it in calibration). The top level is the simulator that is
calibrated; the cheaper ones teach it where their runs are dense.

- Hyperparameters, level by level (the recursive formulation of Le Gratiet
  & Garnier 2014): g_1's are emulator.stan's posterior mode on the cheapest
  runs; g_k's and rho_k are the mode of the same priors (rho_k flat) on the
  residuals y_k - rho_k z_{k-1}, where z_{k-1} is level k-1 at level k's
  runs: its own output where a run was made at both levels (nested
  designs), else the emulator's mean of level k-1 there.
- Prediction: co-kriging given every level's runs at once (Kennedy &
  O'Hagan 2000, section 2.2), exact for nested and non-nested designs
  alike: the levels' joint covariance is
      cov(f_a(s), f_b(t)) = sum_{j <= min(a, b)} P(j, a) P(j, b) k_j(s, t),
  P(j, a) = rho_{j+1} ... rho_a (P(a, a) = 1). For nested designs without
  noise it equals Le Gratiet & Garnier's recursive formulas
  (tests/test_multifidelity_numerics.py keeps them as the check).
- Leave-one-out errors at the top level's runs, with and without the
  cheaper runs (Dubrule 1983: the left-out residual is alpha_i / [K^-1]_ii),
  say whether the cheap runs help.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy import linalg, optimize

from stancal.numerics.scalable_emulator import (
    Hyperparameters,
    fit_hyperparameters,
    negative_log_posterior,
    pack,
    run_nugget_variance,
    se_correlation,
    unpack,
)

RHO_STEP = 1e-5  # central difference for rho's gradient: the objective is smooth and cheap in it
RHO_NEGLIGIBLE = 0.1  # |rho| sd_below / sd_own under this: the cheaper level explains little
SAME_RUN = 1e-9  # runs at two levels this close in the unit cube are one design point


@dataclass
class Level:
    """One level's GP g_k and the scale rho_k of the level below (1 for the cheapest, unused)."""

    hyperparameters: Hyperparameters
    rho: float
    xt: np.ndarray  # (n_k, D + Q) runs of this level, unit cube
    y: np.ndarray  # (n_k,) their outputs, standardised


def _scale(levels: list[Level], below: int, level: int) -> float:
    """P(below, level): the product of rho over the levels above ``below`` up to ``level``."""
    return float(np.prod([levels[m].rho for m in range(below + 1, level + 1)]))


def level_covariance(levels: list[Level], s: np.ndarray, a: int, t: np.ndarray, b: int) -> np.ndarray:
    """cov(f_a(s), f_b(t)) without nuggets, levels counted from 0."""
    out = np.zeros((len(s), len(t)))
    for j in range(min(a, b) + 1):
        h = levels[j].hyperparameters
        out += _scale(levels, j, a) * _scale(levels, j, b) * h.sd**2 * se_correlation(s, t, h.length_scale)
    return out


def level_mean(levels: list[Level], a: int) -> float:
    """E f_a: each GP's constant mean carried up by the scales."""
    return sum(_scale(levels, j, a) * levels[j].hyperparameters.mean for j in range(a + 1))


def joint_covariance(levels: list[Level]) -> np.ndarray:
    """The covariance of every level's runs, cheapest level's first, with
    each run's own nugget and the jitter of run_covariance on its diagonal."""
    blocks = [[level_covariance(levels, levels[a].xt, a, levels[b].xt, b) for b in range(len(levels))]
              for a in range(len(levels))]
    K = np.block(blocks)
    diagonal = np.concatenate([np.full(len(lv.y), run_nugget_variance(lv.hyperparameters)) for lv in levels])
    K[np.diag_indices_from(K)] += diagonal
    return K


def _stacked(levels: list[Level]) -> tuple[np.ndarray, np.ndarray]:
    """All runs' outputs minus their level's mean, and each run's level."""
    residual = np.concatenate([lv.y - level_mean(levels, a) for a, lv in enumerate(levels)])
    which = np.concatenate([np.full(len(lv.y), a) for a, lv in enumerate(levels)])
    return residual, which


def predictive(levels: list[Level], points: np.ndarray, level: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Co-kriging mean and covariance of f_level (default the top) at
    ``points`` given every level's runs (no nugget at the points: the
    simulator is deterministic there)."""
    top = len(levels) - 1 if level is None else level
    factor, alpha = _conditioned(levels)
    cross = _cross(levels, points, top)
    return (level_mean(levels, top) + cross @ alpha,
            level_covariance(levels, points, top, points, top) - cross @ linalg.cho_solve(factor, cross.T))


def predict(levels: list[Level], points: np.ndarray, level: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The mean and variance of ``predictive``."""
    mean, covariance = predictive(levels, points, level)
    return mean, np.maximum(np.diag(covariance), 0.0)


def mean_function(levels: list[Level]) -> Callable[[np.ndarray], np.ndarray]:
    """The top level's co-kriging mean as a function of points, with the
    runs' factorisation done once (for many calls: the L2 projection)."""
    _, alpha = _conditioned(levels)
    top = len(levels) - 1
    mean = level_mean(levels, top)
    return lambda points: mean + _cross(levels, points, top) @ alpha


def _conditioned(levels: list[Level]) -> tuple[tuple[np.ndarray, bool], np.ndarray]:
    """The Cholesky factor of every run's covariance and K^-1 (y - E y)."""
    factor = linalg.cho_factor(joint_covariance(levels), lower=True)
    return factor, linalg.cho_solve(factor, _stacked(levels)[0])


def _cross(levels: list[Level], points: np.ndarray, level: int) -> np.ndarray:
    """cov(f_level(points), every run), cheapest level's runs first."""
    return np.hstack([level_covariance(levels, points, level, lv.xt, a) for a, lv in enumerate(levels)])


def matching_runs(xt: np.ndarray, xt_below: np.ndarray) -> np.ndarray:
    """For each run in ``xt``, the index of the same design point among
    ``xt_below``, or -1 where the level below has no run there."""
    distance = np.abs(xt[:, None, :] - xt_below[None, :, :]).max(axis=2)
    nearest = distance.argmin(axis=1)
    return np.where(distance[np.arange(len(xt)), nearest] < SAME_RUN, nearest, -1)


def level_objective(v: np.ndarray, xt: np.ndarray, y: np.ndarray, below: np.ndarray) -> tuple[float, np.ndarray]:
    """negative_log_posterior of g_k on y - rho z, v = (rho, u); rho's
    derivative by a central difference (one more factorisation each side)."""
    value, grad_u = negative_log_posterior(v[1:], xt, y - v[0] * below)
    up, _ = negative_log_posterior(v[1:], xt, y - (v[0] + RHO_STEP) * below)
    down, _ = negative_log_posterior(v[1:], xt, y - (v[0] - RHO_STEP) * below)
    return value, np.concatenate([[(up - down) / (2 * RHO_STEP)], grad_u])


def level_below(levels: list[Level], xt: np.ndarray) -> np.ndarray:
    """z_{k-1} at the runs ``xt`` of the next level: the level below's own
    output where it was run there, else its co-kriging mean."""
    matched = matching_runs(xt, levels[-1].xt)
    out = np.where(matched >= 0, levels[-1].y[np.maximum(matched, 0)], 0.0)
    if (matched < 0).any():
        out[matched < 0] = mean_function(levels)(xt[matched < 0])
    return out


def fit_level(levels: list[Level], xt: np.ndarray, y: np.ndarray, seed: int) -> Level:
    """rho_k and g_k's hyperparameters at their joint posterior mode, given
    the levels below (fitted already: the recursive formulation)."""
    below = level_below(levels, xt)
    slope = np.polyfit(below, y, 1)[0] if np.ptp(below) > 0 else 1.0
    start, _ = fit_hyperparameters(xt, y - slope * below, seed)
    found = optimize.minimize(level_objective, np.concatenate([[slope], pack(start)]), args=(xt, y, below),
                              jac=True, method="L-BFGS-B", options={"maxiter": 500})
    best = found.x if np.isfinite(found.fun) else np.concatenate([[slope], pack(start)])
    return Level(unpack(best[1:]), float(best[0]), xt, y)


def fit_levels(xt: list[np.ndarray], y: list[np.ndarray], seed: int = 0) -> list[Level]:
    """Every level's hyperparameters, cheapest first, level by level."""
    h, _ = fit_hyperparameters(xt[0], y[0], seed)
    levels = [Level(h, 1.0, xt[0], y[0])]
    for k in range(1, len(xt)):
        levels.append(fit_level(levels, xt[k], y[k], seed + k))
    return levels


def loo_errors(levels: list[Level]) -> np.ndarray:
    """Leave-one-out residuals at the top level's runs given all other runs
    of every level, hyperparameters fixed (Dubrule 1983)."""
    factor = linalg.cho_factor(joint_covariance(levels), lower=True)
    precision = linalg.cho_solve(factor, np.eye(sum(len(lv.y) for lv in levels)))
    residual, which = _stacked(levels)
    top = which == len(levels) - 1
    return (precision @ residual)[top] / np.diag(precision)[top]


@dataclass
class CheapRunsValue:
    """What the cheaper levels add to the top level's emulator."""

    rho: list[float]  # rho_2..rho_K
    loo_with: float  # RMS leave-one-out error at the top level's runs, standardised units
    loo_without: float  # the same from a GP of the top level's runs alone
    negligible: list[bool]  # per rho: the level below explains little of the one above

    @property
    def helps(self) -> bool:
        return self.loo_with < self.loo_without and not any(self.negligible)

    def warning(self) -> str | None:
        """One line for the log and the report when the cheap runs do not help."""
        if self.helps:
            return None
        return (f"the low-fidelity runs do not help the emulator: leave-one-out error at the high-fidelity "
                f"runs {self.loo_with:.3g} with them, {self.loo_without:.3g} without (standardised units); "
                f"rho = {', '.join(f'{r:.3g}' for r in self.rho)}")


def cheap_runs_value(levels: list[Level], seed: int = 0) -> CheapRunsValue:
    """Leave-one-out at the top level's runs with every level against a GP
    of the top level's runs alone, and whether each rho is negligible
    (|rho_k| sd_{k-1} below RHO_NEGLIGIBLE times g_k's sd)."""
    top = levels[-1]
    h, _ = fit_hyperparameters(top.xt, top.y, seed)
    alone = [Level(h, 1.0, top.xt, top.y)]
    rms = [float(np.sqrt(np.mean(loo_errors(lv) ** 2))) for lv in (levels, alone)]
    below_sd = [np.sqrt(level_covariance(levels, top.xt[:1], k - 1, top.xt[:1], k - 1)[0, 0])
                for k in range(1, len(levels))]
    negligible = [abs(levels[k].rho) * below_sd[k - 1] < RHO_NEGLIGIBLE * levels[k].hyperparameters.sd
                  for k in range(1, len(levels))]
    return CheapRunsValue([lv.rho for lv in levels[1:]], rms[0], rms[1], negligible)
