"""Stage 1 of a two-level emulator whose cheap level has its own
calibration parameters theta_l (Goh et al. 2013, Technometrics 55(4),
"Prediction and computer model calibration using outputs from
multifidelity simulators"; review section 8.3):

    f_top(x, theta) = rho f_1(x, theta_l) + g_2(x, theta),

with f_1 a GP over the cheap runs' (x, theta_l) and g_2 a GP over (x, theta).
The expensive runs were made without theta_l: their cheap part is the cheap
simulator at the same best setting theta_l as the physical data's (Goh et
al. 2013, section 2), so theta_l enters their covariance with the cheap
runs, and stage 2 samples it with theta (modular.stan,
functions/fidelity_theta.stan).

Every point lives in (x, theta, theta_l) on the unit cube, and each level's
GP ignores the parameters that are not its own: they get the length scale
INACTIVE, whose kernel factor is exactly 1 in double precision. Then the
levels are stancal.numerics.multifidelity's, and its co-kriging, leave-one-
out and Stan data hold unchanged.

Hyperparameters, level by level (Le Gratiet & Garnier 2014): f_1's at
emulator.stan's posterior mode on the cheap runs' (x, theta_l); then theta_l,
rho and g_2's at their joint mode on y_2 - rho z_1(theta_l), z_1 the cheap
level's co-kriging mean at the expensive runs' (x, theta_l), from several
starts of theta_l (the objective can have several modes in it).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from scipy import optimize

from stancal.numerics.multifidelity import Level, level_objective, mean_function, rho_start
from stancal.numerics.scalable_emulator import Hyperparameters, fit_hyperparameters, pack, unpack

INACTIVE = 1e10  # a length scale whose squared-exponential factor is exactly 1 over the unit cube
THETA_LOW_STARTS = 5  # starts of theta_l on a grid of the unit cube (one parameter: 0.1, 0.3, ..., 0.9)
THETA_LOW_STEP = 1e-5  # central difference for theta_l's gradient


def with_inactive(h: Hyperparameters, before: int, after: int, at: int) -> Hyperparameters:
    """h's length scales with ``before`` INACTIVE ones inserted at position
    ``at`` and ``after`` appended: the GP extended to inputs it ignores."""
    ls = h.length_scale
    return replace(h, length_scale=np.concatenate([ls[:at], np.full(before, INACTIVE), ls[at:],
                                                   np.full(after, INACTIVE)]))


def cheap_points(x: np.ndarray, theta_low: np.ndarray, q: int) -> np.ndarray:
    """Points (x, theta, theta_l) of the cheap simulator: theta, which it lacks, at the box's centre (unused)."""
    return np.hstack([x, np.full((len(x), q), 0.5), theta_low])


def expensive_points(x: np.ndarray, theta: np.ndarray, theta_low: np.ndarray) -> np.ndarray:
    """Points (x, theta, theta_l) of the expensive simulator at one theta_l."""
    return np.hstack([x, theta, np.tile(theta_low, (len(x), 1))])


def fit_levels_theta_low(x: list[np.ndarray], theta: list[np.ndarray], y: list[np.ndarray],
                         seed: int = 0) -> tuple[list[Level], np.ndarray]:
    """The two levels, cheap first, in (x, theta, theta_l) coordinates, and
    theta_l's stage-1 estimate on the unit cube. ``theta[0]`` holds the cheap
    runs' theta_l, ``theta[1]`` the expensive runs' theta (unit cube)."""
    d, q, q_low = x[0].shape[1], theta[1].shape[1], theta[0].shape[1]
    h1, _ = fit_hyperparameters(np.hstack([x[0], theta[0]]), y[0], seed)
    cheap = Level(with_inactive(h1, q, 0, d), 1.0, cheap_points(x[0], theta[0], q), y[0])
    mean = mean_function([cheap])
    xt = np.hstack([x[1], theta[1]])

    def below(theta_low: np.ndarray) -> np.ndarray:
        return mean(expensive_points(x[1], theta[1], theta_low))

    def objective(v: np.ndarray) -> tuple[float, np.ndarray]:
        value, grad = level_objective(v[q_low:], xt, y[1], below(v[:q_low]))
        steps = [(level_objective(v[q_low:], xt, y[1], below(v[:q_low] + THETA_LOW_STEP * e))[0]
                  - level_objective(v[q_low:], xt, y[1], below(v[:q_low] - THETA_LOW_STEP * e))[0])
                 / (2 * THETA_LOW_STEP) for e in np.eye(q_low)]
        return value, np.concatenate([steps, grad])

    # g_2's hyperparameters from the box's centre start every search (one GP fit, not one per start)
    centre = np.full(q_low, 0.5)
    h, _ = fit_hyperparameters(xt, y[1] - _slope(below(centre), y[1]) * below(centre), seed)
    best = min((_from_start(objective, start, y[1], below(start), h) for start in _theta_low_starts(q_low)),
               key=lambda found: found.fun)
    theta_low, v = best.x[:q_low], best.x[q_low:]
    top = Level(with_inactive(unpack(v[1:]), 0, q_low, d + q), float(v[0]),
                expensive_points(x[1], theta[1], theta_low), y[1])
    return [cheap, top], theta_low


def _theta_low_starts(q_low: int) -> list[np.ndarray]:
    """A grid of starts: each parameter at THETA_LOW_STARTS evenly spaced values (a diagonal when several)."""
    grid = (np.arange(THETA_LOW_STARTS) + 0.5) / THETA_LOW_STARTS
    return [np.full(q_low, g) for g in grid]


def _slope(below: np.ndarray, y: np.ndarray) -> float:
    """rho's start: y's regression on the level below, with an intercept (1 where that is constant)."""
    return float(rho_start(y, below[:, None])[0])


def _from_start(objective, start: np.ndarray, y: np.ndarray, below: np.ndarray, h: Hyperparameters):
    """L-BFGS-B from theta_l = start, rho by regression there, g_2's hyperparameters at ``h``."""
    v0 = np.concatenate([start, [_slope(below, y)], pack(h)])
    bounds = [(0.0, 1.0)] * len(start) + [(None, None)] * (len(v0) - len(start))
    found = optimize.minimize(objective, v0, jac=True, method="L-BFGS-B", bounds=bounds, options={"maxiter": 500})
    if not np.isfinite(found.fun):
        found.x, found.fun = v0, objective(v0)[0]
    return found
