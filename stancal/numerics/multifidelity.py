"""The multi-fidelity emulator: the autoregressive model of Kennedy &
O'Hagan (2000) for simulators of K levels of fidelity, cheapest first,

    f_1(t) = g_1(t),    f_k(t) = rho_k f_{k-1}(t) + g_k(t)   (k = 2..K),

with independent GPs g_k over t = (x, theta) (squared exponential, the
kernel of stage 1) and scales rho_k (review section 8.3; Goh et al. 2013
use it in calibration): constant, or linear in the simulator's inputs,
rho_k(x) = beta_0 + x' beta_x on the unit cube (Le Gratiet & Garnier 2014,
section 2: rho as a regression on the inputs; Kennedy & O'Hagan 2000,
section 2.1). rho depends on x alone, not on theta, so at the physical
points (which share theta) the levels' weights are data. The top level is
the simulator that is calibrated; the cheaper ones teach it where their
runs are dense.

- Hyperparameters, level by level (the recursive formulation of Le Gratiet
  & Garnier 2014): g_1's are emulator.stan's posterior mode on the cheapest
  runs; g_k's and rho_k's coefficients are the mode of the same priors
  (rho_k's flat) on the residuals y_k - rho_k(x) z_{k-1}; at that mode the
  coefficients are their generalised least-squares estimate given g_k's
  hyperparameters, in closed form (Le Gratiet & Garnier 2014). z_{k-1} is
  level k-1 at level k's runs: its own output where a run was made at both
  levels (nested designs), else the emulator's mean of level k-1 there.
- Prediction: co-kriging given every level's runs at once (Kennedy &
  O'Hagan 2000, section 2.2), exact for nested and non-nested designs
  alike: the levels' joint covariance is
      cov(f_a(s), f_b(t)) = sum_{j <= min(a, b)} P(j, a) P(j, b) k_j(s, t),
  P(j, a) = rho_{j+1} ... rho_a (P(a, a) = 1), each rho at the point.
  For nested designs without noise it equals Le Gratiet & Garnier's recursive formulas
  (tests/test_multifidelity_numerics.py keeps them as the check).
- Leave-one-out errors at the top level's runs, with and without the
  cheaper runs (Dubrule 1983: the left-out residual is alpha_i / [K^-1]_ii),
  say whether the cheap runs help.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from scipy import linalg, optimize

from stancal.numerics.scalable_emulator import (
    JITTER,
    Hyperparameters,
    fit_hyperparameters,
    negative_log_posterior,
    pack,
    run_covariance,
    run_nugget_variance,
    se_correlation,
    unpack,
)

RHO_STEP = 1e-5  # central difference for rho's gradient: the objective is smooth and cheap in it
RHO_NEGLIGIBLE = 0.1  # |rho| sd_below / sd_own under this: the cheaper level explains little
SAME_RUN = 1e-9  # runs at two levels this close in the unit cube are one design point


@dataclass
class Level:
    """One level's GP g_k and the scale rho_k of the level below (1 for the cheapest, unused):
    rho_k(x) = rho + x' rho_slope, x the first len(rho_slope) columns of a point (its simulator
    inputs on the unit cube); no slope: a constant rho."""

    hyperparameters: Hyperparameters
    rho: float
    xt: np.ndarray  # (n_k, D + Q) runs of this level, unit cube
    y: np.ndarray  # (n_k,) their outputs, standardised
    rho_slope: np.ndarray = field(default_factory=lambda: np.zeros(0))  # (D,) or empty: constant rho

    @property
    def rho_coefficients(self) -> np.ndarray:
        """(rho, rho_slope): the coefficients of rho_design's columns."""
        return np.concatenate([[self.rho], self.rho_slope])

    def rho_at(self, points: np.ndarray) -> np.ndarray:
        """rho_k at each point."""
        return rho_design(points, len(self.rho_slope)) @ self.rho_coefficients


def rho_design(points: np.ndarray, slopes: int) -> np.ndarray:
    """rho's regressors at each point: 1, then the first ``slopes`` columns (the simulator's inputs)."""
    return np.hstack([np.ones((len(points), 1)), points[:, :slopes]])


def rho_range(level: Level) -> tuple[float, float]:
    """The least and largest rho_k over the unit box of the inputs (a linear
    rho's extremes are at corners: each slope at its own end)."""
    s = level.rho_slope
    return level.rho + float(np.minimum(s, 0).sum()), level.rho + float(np.maximum(s, 0).sum())


# where rho_profile reads rho along each input, on the unit box (the report gives the inputs there in their units)
RHO_PROFILE_GRID = np.linspace(0, 1, 5)


def rho_profile(level: Level) -> np.ndarray:
    """rho_k along each of its inputs at RHO_PROFILE_GRID, the other inputs
    at the centre: (inputs, points)."""
    grid = RHO_PROFILE_GRID
    return np.array([level.rho + level.rho_slope @ np.full(len(level.rho_slope), 0.5)
                     + level.rho_slope[d] * (grid - 0.5) for d in range(len(level.rho_slope))])


def _scale(levels: list[Level], below: int, level: int, points: np.ndarray) -> np.ndarray:
    """P(below, level) at each point: the product of rho over the levels above ``below`` up to ``level``."""
    out = np.ones(len(points))
    for m in range(below + 1, level + 1):
        out = out * levels[m].rho_at(points)
    return out


def level_covariance(levels: list[Level], s: np.ndarray, a: int, t: np.ndarray, b: int) -> np.ndarray:
    """cov(f_a(s), f_b(t)) without nuggets, levels counted from 0."""
    out = np.zeros((len(s), len(t)))
    for j in range(min(a, b) + 1):
        h = levels[j].hyperparameters
        scales = np.outer(_scale(levels, j, a, s), _scale(levels, j, b, t))
        out += scales * h.sd**2 * se_correlation(s, t, h.length_scale)
    return out


def level_mean(levels: list[Level], a: int, points: np.ndarray) -> np.ndarray:
    """E f_a at each point: each GP's constant mean carried up by the scales."""
    return sum(_scale(levels, j, a, points) * levels[j].hyperparameters.mean for j in range(a + 1))


def joint_covariance(levels: list[Level], top_jitter: bool = False) -> np.ndarray:
    """The covariance of every level's runs, cheapest level's first, with
    each run's own nugget and the jitter of run_covariance on its diagonal;
    ``top_jitter``: the jitter of the top level's prior variance on every
    run instead, as fidelity_run_cov of functions/fidelity.stan (constant rho)."""
    blocks = [[level_covariance(levels, levels[a].xt, a, levels[b].xt, b) for b in range(len(levels))]
              for a in range(len(levels))]
    K = np.block(blocks)
    if top_jitter:
        corner = np.zeros((1, levels[-1].xt.shape[1]))
        top = len(levels) - 1
        jitter = JITTER * level_covariance(levels, corner, top, corner, top)[0, 0]
        diagonal = np.concatenate([np.full(len(lv.y), lv.hyperparameters.nugget**2 + jitter) for lv in levels])
    else:
        diagonal = np.concatenate([np.full(len(lv.y), run_nugget_variance(lv.hyperparameters)) for lv in levels])
    K[np.diag_indices_from(K)] += diagonal
    return K


def stacked_residuals(levels: list[Level]) -> np.ndarray:
    """Every level's runs' outputs minus their level's prior mean, cheapest level's first."""
    return _stacked(levels)[0]


def _stacked(levels: list[Level]) -> tuple[np.ndarray, np.ndarray]:
    """All runs' outputs minus their level's mean, and each run's level."""
    residual = np.concatenate([lv.y - level_mean(levels, a, lv.xt) for a, lv in enumerate(levels)])
    which = np.concatenate([np.full(len(lv.y), a) for a, lv in enumerate(levels)])
    return residual, which


def predictive(levels: list[Level], points: np.ndarray, level: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Co-kriging mean and covariance of f_level (default the top) at
    ``points`` given every level's runs (no nugget at the points: the
    simulator is deterministic there)."""
    top = len(levels) - 1 if level is None else level
    factor, alpha = _conditioned(levels)
    cross = cross_covariance(levels, points, top)
    return (level_mean(levels, top, points) + cross @ alpha,
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
    return lambda points: level_mean(levels, top, points) + cross_covariance(levels, points, top) @ alpha


def _conditioned(levels: list[Level]) -> tuple[tuple[np.ndarray, bool], np.ndarray]:
    """The Cholesky factor of every run's covariance and K^-1 (y - E y)."""
    factor = linalg.cho_factor(joint_covariance(levels), lower=True)
    return factor, linalg.cho_solve(factor, _stacked(levels)[0])


def cross_covariance(levels: list[Level], points: np.ndarray, level: int) -> np.ndarray:
    """cov(f_level(points), every run), cheapest level's runs first."""
    return np.hstack([level_covariance(levels, points, level, lv.xt, a) for a, lv in enumerate(levels)])


def matching_runs(xt: np.ndarray, xt_below: np.ndarray) -> np.ndarray:
    """For each run in ``xt``, the index of the same design point among
    ``xt_below``, or -1 where the level below has no run there."""
    distance = np.abs(xt[:, None, :] - xt_below[None, :, :]).max(axis=2)
    nearest = distance.argmin(axis=1)
    return np.where(distance[np.arange(len(xt)), nearest] < SAME_RUN, nearest, -1)


def level_objective(v: np.ndarray, xt: np.ndarray, y: np.ndarray, below: np.ndarray,
                    design: np.ndarray | None = None) -> tuple[float, np.ndarray]:
    """negative_log_posterior of g_k on y - rho(x) z, v = (rho's coefficients, u),
    rho(x) = design @ coefficients (default one column of ones: a constant rho);
    each coefficient's derivative by a central difference (two more factorisations)."""
    design = np.ones((len(y), 1)) if design is None else design
    scaled = design * below[:, None]  # the runs' regressors of rho times z
    r = design.shape[1]
    value, grad_u = negative_log_posterior(v[r:], xt, y - scaled @ v[:r])
    steps = [(negative_log_posterior(v[r:], xt, y - scaled @ (v[:r] + RHO_STEP * e))[0]
              - negative_log_posterior(v[r:], xt, y - scaled @ (v[:r] - RHO_STEP * e))[0]) / (2 * RHO_STEP)
             for e in np.eye(r)]
    return value, np.concatenate([steps, grad_u])


def gls_rho(levels: list[Level], level: int) -> np.ndarray:
    """rho_k's coefficients by generalised least squares given g_k's
    hyperparameters, in closed form (Le Gratiet & Garnier 2014):
    (G' K^-1 G)^-1 G' K^-1 (y_k - m_k), G = diag(z_{k-1}) F, F rho_design at
    level k's runs and K g_k's covariance of them. At stage 1's mode the
    coefficients equal it (rho's prior is flat)."""
    lv = levels[level]
    scaled = rho_design(lv.xt, len(lv.rho_slope)) * level_below(levels[:level], lv.xt)[:, None]
    factor = linalg.cho_factor(run_covariance(lv.xt, lv.hyperparameters), lower=True)
    weighted = linalg.cho_solve(factor, scaled)
    return np.linalg.solve(scaled.T @ weighted, weighted.T @ (lv.y - lv.hyperparameters.mean))


def level_below(levels: list[Level], xt: np.ndarray) -> np.ndarray:
    """z_{k-1} at the runs ``xt`` of the next level: the level below's own
    output where it was run there, else its co-kriging mean."""
    matched = matching_runs(xt, levels[-1].xt)
    out = np.where(matched >= 0, levels[-1].y[np.maximum(matched, 0)], 0.0)
    if (matched < 0).any():
        out[matched < 0] = mean_function(levels)(xt[matched < 0])
    return out


def rho_start(y: np.ndarray, scaled: np.ndarray) -> np.ndarray:
    """rho's coefficients' start: y's least-squares regression on rho's
    regressors times the level below, with an intercept (1 where z is constant)."""
    if np.ptp(scaled[:, 0]) == 0:
        return np.concatenate([[1.0], np.zeros(scaled.shape[1] - 1)])
    return np.linalg.lstsq(np.column_stack([scaled, np.ones(len(y))]), y, rcond=None)[0][:-1]


def fit_level(levels: list[Level], xt: np.ndarray, y: np.ndarray, seed: int, slopes: int = 0) -> Level:
    """rho_k's coefficients and g_k's hyperparameters at their joint
    posterior mode, given the levels below (fitted already: the recursive
    formulation); ``slopes``: rho_k linear in the first ``slopes`` columns
    (the simulator's inputs), 0 for a constant rho_k."""
    below = level_below(levels, xt)
    design = rho_design(xt, slopes)
    coefficients = rho_start(y, design * below[:, None])
    start, _ = fit_hyperparameters(xt, y - design @ coefficients * below, seed)
    v0 = np.concatenate([coefficients, pack(start)])
    found = optimize.minimize(level_objective, v0, args=(xt, y, below, design),
                              jac=True, method="L-BFGS-B", options={"maxiter": 500})
    best = found.x if np.isfinite(found.fun) else v0
    r = design.shape[1]
    return Level(unpack(best[r:]), float(best[0]), xt, y, best[1:r])


def fit_levels(xt: list[np.ndarray], y: list[np.ndarray], seed: int = 0, slopes: int = 0) -> list[Level]:
    """Every level's hyperparameters, cheapest first, level by level; ``slopes``
    as fit_level's (rho linear in the simulator's inputs, or 0: constant)."""
    h, _ = fit_hyperparameters(xt[0], y[0], seed)
    levels = [Level(h, 1.0, xt[0], y[0])]
    for k in range(1, len(xt)):
        levels.append(fit_level(levels, xt[k], y[k], seed + k, slopes))
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

    rho: list[float]  # rho_2..rho_K (a linear rho's intercept: its value at the box's lower corner)
    loo_with: float  # RMS leave-one-out error at the top level's runs, standardised units
    loo_without: float  # the same from a GP of the top level's runs alone
    negligible: list[bool]  # per rho: the level below explains little of the one above
    rho_slope: list[list[float]] = field(default_factory=list)  # per rho: its slopes on the inputs (unit cube)
    rho_range: list[tuple[float, float]] = field(default_factory=list)  # per rho: least and largest over the box

    @property
    def helps(self) -> bool:
        return self.loo_with < self.loo_without and not any(self.negligible)

    def rho_text(self) -> str:
        """Each rho: its value, or a linear rho's range over the inputs' box."""
        return ", ".join(f"{r:.3g}" if not any(s) else f"{lo:.3g} to {hi:.3g} over the inputs' box"
                         for r, s, (lo, hi) in zip(self.rho, self.rho_slope, self.rho_range, strict=True))

    def warning(self) -> str | None:
        """One line for the log and the report when the cheap runs do not help."""
        if self.helps:
            return None
        return (f"the low-fidelity runs do not help the emulator: leave-one-out error at the high-fidelity "
                f"runs {self.loo_with:.3g} with them, {self.loo_without:.3g} without (standardised units); "
                f"rho = {self.rho_text()}")


def cheap_runs_value(levels: list[Level], seed: int = 0) -> CheapRunsValue:
    """Leave-one-out at the top level's runs with every level against a GP
    of the top level's runs alone, and whether each rho is negligible
    (|rho_k| sd_{k-1} below RHO_NEGLIGIBLE times g_k's sd, with a linear
    rho_k's largest |rho_k| over the inputs' box: negligible everywhere)."""
    top = levels[-1]
    h, _ = fit_hyperparameters(top.xt, top.y, seed)
    alone = [Level(h, 1.0, top.xt, top.y)]
    rms = [float(np.sqrt(np.mean(loo_errors(lv) ** 2))) for lv in (levels, alone)]
    ranges = [rho_range(lv) for lv in levels[1:]]
    # level k-1's prior sd at the box's lower corner: a point where each rho is its intercept
    corner = np.zeros((1, top.xt.shape[1]))
    below_sd = [np.sqrt(level_covariance(levels, corner, k - 1, corner, k - 1)[0, 0]) for k in range(1, len(levels))]
    negligible = [max(abs(lo), abs(hi)) * below_sd[k - 1] < RHO_NEGLIGIBLE * levels[k].hyperparameters.sd
                  for k, (lo, hi) in enumerate(ranges, start=1)]
    return CheapRunsValue([lv.rho for lv in levels[1:]], rms[0], rms[1], negligible,
                          [lv.rho_slope.tolist() for lv in levels[1:]], ranges)
