"""The next physical experiments: the input settings whose measurements
would most reduce theta's posterior variance, averaged over the theta not
ruled out (a pseudo-Bayesian A-optimal design, Chaloner & Verdinelli 1995,
"Bayesian experimental design: a review", Stat. Sci. 10, section 2.3).

theta's posterior covariance is taken as the inverse of its Fisher
information under the emulator's linearisation, J = P0 + G' V^-1 G, with
G the derivatives of E[f(x_i, theta)] in theta at every measured value
(central differences on theta's unit cube), V the values' covariance
(noise and emulator variance on the diagonal, plus the discrepancy's,
correlated between values by a squared exponential of length
DISCREPANCY_LENGTH over the inputs' unit cube and, for a vector output, the
output index's range: a value close to one already measured shares its
discrepancy and teaches less; the length is the calibration's, its
posterior median, when a fit of the problem is at hand (the posterior
criterion's), else DISCREPANCY_LENGTH, a fifth of each range: a
discrepancy that varies smoothly over the settings, as the GP prior's
length scales in stancal's programs centre on), and P0 = 12 I the precision of theta's
uniform prior on its unit cube. The criterion is the mean over NROY draws
of trace(J^-1); settings are added one at a time, each the candidate of a
Latin hypercube of the inputs' range that lowers it most, each candidate's
information given what is known through the Schur complement of its
values' covariance (J and V^-1 recomputed from every value after each
pick). Censored rows are left out of what is known (their information is
less than a value's), and counts enter on the link scale with the
targets' delta-method variances. With per-experiment theta a new
experiment brings its own theta, unknown: the criterion is then the
variance of the shared theta, with every experiment's own (the new one's
too) in J (greedy_settings). This is chosen over the IMSPE of
zeta (Leatherman et al. 2017) because the design loop's goal is theta, and
because it needs only the emulator and the stated variances, not a fitted
discrepancy GP, so it works at every wave."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.stats import qmc

from stancal.designing.implausibility import Cut

SETTINGS_CANDIDATES = 300
THETA_DRAWS = 16
STEP = 1e-3  # theta's unit cube
DISCREPANCY_LENGTH = 0.2  # without a fit: the discrepancy's correlation length, unit cube of the inputs
# (and output index)


def _jacobian(evaluate, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """d mean / d theta (S, n, Q) at each draw of theta (S, Q), by central
    differences of ``evaluate`` (theta -> the emulator's mean and variance,
    each (S, n)), and each value's emulator variance averaged over the draws (n,)."""
    S, Q = theta.shape
    shifted = [theta]
    for q in range(Q):
        for sign in (1, -1):
            moved = theta.copy()
            moved[:, q] = np.clip(moved[:, q] + sign * STEP, 0, 1)
            shifted.append(moved)
    mean, variance = evaluate(np.vstack(shifted))
    mean = mean.reshape(1 + 2 * Q, S, -1)
    steps = np.stack([shifted[1 + 2 * q][:, q] - shifted[2 + 2 * q][:, q] for q in range(Q)], axis=-1)  # (S, Q)
    gradient = np.stack([mean[1 + 2 * q] - mean[2 + 2 * q] for q in range(Q)], axis=-1) / steps[:, None, :]
    return gradient, variance[:S].mean(axis=0)


def index_range(targets) -> tuple[np.ndarray, np.ndarray]:
    """The observed output indices' low end and width per column (a
    vector output's; empty for a scalar one), the unit the discrepancy's
    position along the output is measured in."""
    every_index = np.vstack([g[2] for g in targets.groups]) if targets.groups else np.zeros((1, 0))
    width = np.ptp(every_index, axis=0)
    return every_index.min(axis=0), width + (width == 0)


def positions(x_unit: np.ndarray, groups, index_low: np.ndarray, index_width: np.ndarray) -> np.ndarray:
    """Where each value's discrepancy sits: its inputs and, for a vector output, its output index (unit range)."""
    if not groups:
        return x_unit
    index = np.zeros((len(x_unit), len(index_low)))
    for _, values, indices in groups:
        index[values] = (indices - index_low) / index_width
    return np.column_stack([x_unit, index])


def discrepancy_covariance(cut: Cut, a: np.ndarray, b: np.ndarray,
                           length: float | np.ndarray = DISCREPANCY_LENGTH) -> np.ndarray:
    """The discrepancy's squared-exponential covariance between positions;
    ``length``: one, or one per position column."""
    squared = (((a[:, None, :] - b[None, :, :]) / length) ** 2).sum(-1)
    return cut.targets.discrepancy_variance * np.exp(-0.5 * squared)


def next_experiments(cut: Cut, nroy_theta: np.ndarray, count: int, seed: int,
                     length: float | np.ndarray = DISCREPANCY_LENGTH,
                     box=None) -> tuple[np.ndarray, list[float]]:
    """``count`` input settings (count, D), unit cube of the inputs, and the
    criterion (mean trace of the shared theta's covariance, unit cube) after
    each pick. ``length``: the discrepancy's length scales on the positions'
    unit cube (the inputs', then the output index's, index_range).
    ``box``: NROY's UnitBox (needed with per-experiment theta: its shared
    columns, and run_theta, the theta a new experiment's values are emulated
    at: each draw's shared theta and a random experiment's own, a value the
    new experiment's own may take); a new experiment brings its own theta."""
    targets = cut.targets
    inputs = targets.x_unit.shape[1]
    if not inputs:
        raise ValueError("--experiments needs simulator inputs to choose ([physical] inputs is empty)")
    if targets.group_theta and box is None:
        raise ValueError("with per-experiment theta, next_experiments needs NROY's box (its shared theta)")
    rng = np.random.default_rng(seed)
    theta = nroy_theta[rng.choice(len(nroy_theta), min(THETA_DRAWS, len(nroy_theta)), replace=False)]
    index_low, index_width = index_range(targets)
    # what is known: the observed values (a censored row's information is less than a value's; left out, it
    # is not overstated); a vector output's values are all observed
    x_known = targets.x_unit if targets.groups else targets.x_unit[targets.observed]
    noise = float(np.mean(targets.noise_variance[targets.observed]))  # a new value's, as the data's on average
    gradient, emulator_variance = _jacobian(lambda t: targets.emulate_at(cut.emulator, x_known, t), theta)
    known = Values(positions(x_known, targets.groups, index_low, index_width), emulator_variance + noise, gradient)
    pool = qmc.LatinHypercube(d=inputs, seed=rng).random(SETTINGS_CANDIDATES)
    pool_x, pool_groups, m = candidate_values(targets, pool)
    pool_gradient, pool_variance = _jacobian(lambda t: cut.emulator.at(pool_x, t, pool_groups),
                                             theta if box is None else box.run_theta(theta, rng))
    candidates = Values(positions(pool_x, pool_groups, index_low, index_width), pool_variance + noise, pool_gradient)
    chosen, criterion = greedy_settings(cut, known, candidates, m, count, length,
                                        theta.shape[1] if box is None else box.shared)
    return pool[chosen], criterion


@dataclass
class Values:
    """Measured values as the criterion sees them: where each one's
    discrepancy sits (positions), its own variance (noise and emulator),
    and the emulator mean's derivatives in theta (S, n, parameters)."""

    where: np.ndarray
    own: np.ndarray
    gradient: np.ndarray


def greedy_settings(cut: Cut, known: Values, pool: Values, m: int, count: int, length: float | np.ndarray,
                    shared: int) -> tuple[list[int], list[float]]:
    """``count`` candidates chosen one at a time, each lowering most the
    mean trace of the shared theta's covariance, (J^-1)'s first ``shared``
    rows and columns: J is the information on every parameter at once, the
    shared theta, each experiment's own (known values) and the candidate's
    own (``pool.gradient``'s columns beyond ``shared``, its prior's
    precision alone until it is measured), so what a candidate's values
    teach about its own theta is not counted as teaching the shared one
    (the Schur complement of J's own block). Without per-experiment theta
    every parameter is shared. A chosen candidate's own theta stays a
    parameter; the next candidate brings new ones."""
    C, S = len(pool.own) // m, known.gradient.shape[0]
    pool_shared, pool_theta = pool.gradient[..., :shared], pool.gradient[..., shared:]
    fresh = pool_theta.shape[-1]  # a new experiment's own theta
    # each candidate's own covariance: the pool never changes, so once
    own_blocks = (np.array([discrepancy_covariance(cut, w, w, length) for w in pool.where.reshape(C, m, -1)])
                  + np.apply_along_axis(np.diag, 1, pool.own.reshape(C, m)))
    where, own, gradient = known.where, known.own, known.gradient
    chosen, criterion = [], []
    for _ in range(count):
        P = gradient.shape[-1] + fresh
        G = np.concatenate([gradient, np.zeros((S, len(own), fresh))], axis=-1)
        candidate = np.concatenate([pool_shared, np.zeros((S, C * m, P - shared - fresh)), pool_theta], axis=-1)
        V_inv = np.linalg.inv(discrepancy_covariance(cut, where, where, length) + np.diag(own))
        information = np.einsum("snq,nk,skr->sqr", G, V_inv, G) + 12 * np.eye(P)
        B = discrepancy_covariance(cut, where, pool.where, length)  # (n, C m)
        solved = V_inv @ B
        schur = own_blocks - np.einsum("nci,ncj->cij", B.reshape(-1, C, m), solved.reshape(-1, C, m))
        U = candidate.reshape(S, C, m, P) - np.einsum("nci,snq->sciq", solved.reshape(-1, C, m), G)
        added = np.einsum("sciq,cij,scjr->scqr", U, np.linalg.inv(schur), U)
        covariance = np.linalg.inv(information[:, None] + added)
        trace = np.trace(covariance[..., :shared, :shared], axis1=-2, axis2=-1).mean(axis=0)
        best = int(np.argmin(trace))
        chosen.append(best)
        criterion.append(float(trace[best]))
        rows = slice(best * m, (best + 1) * m)
        where = np.vstack([where, pool.where[rows]])
        own = np.concatenate([own, pool.own[rows]])
        gradient = np.concatenate([G, candidate[:, rows]], axis=1)
    return chosen, criterion


def candidate_values(targets, pool: np.ndarray):
    """Each candidate setting's measured values: one for a scalar output;
    for a vector output, the output indices of the experiment with the most
    values. Returns their inputs (C * m, D), groups and m."""
    if not targets.groups:
        return pool, (), 1
    indices = max((g[2] for g in targets.groups), key=len)
    m = len(indices)
    groups = [(row, slice(c * m, (c + 1) * m), indices) for c, row in enumerate(pool)]
    return np.repeat(pool, m, axis=0), groups, m
