"""The emulator of modular calibration for thousands of runs
(modular_hsgp.stan's stage 1), with no N x N factorisation per gradient.

- Hyperparameters: emulator.stan's posterior mode on the log scale (the same
  priors and objective as the exact path's stage 1), found by scipy's L-BFGS
  with the analytic gradient on a random subset of at most SUBSET_SIZE runs.
- Mean at (x_i, theta): the exact GP mean of all N runs,
  m + sum_j k(x_i, theta; x_j, theta_j) alpha_j with alpha = K^-1 (y - m)
  computed once, is a smooth function of theta at each point. It is
  interpolated in theta by tensor Chebyshev polynomials through its exact
  values at Chebyshev nodes (Trefethen 2013, Approximation Theory and
  Approximation Practice: exponential convergence, well conditioned), so
  mean_i(theta) = m + weights_i . T(theta), O(n G) per gradient for G nodes,
  with the weights (n x G) precomputed; the degrees grow until the mean is
  within MEAN_TOLERANCE of the exact GP mean at random theta.
- Predictive covariance at the physical points, at one theta (the emulator
  mean's least-squares fit to the data): the emulator's error is smooth, so
  it is correlated across the points, and treated as independent it would
  average out over thousands of points that all share it. Its leading
  eigenvectors (a Nystroem approximation on at most LANDMARKS points,
  Williams & Seeger 2001) enter the likelihood as extra basis functions
  beside the discrepancy's, with fixed weight variances; the rest of each
  point's variance, from a local GP (Gramacy & Apley 2015) on the
  NEIGHBOURS nearest runs in the kernel's metric, is averaged over the
  points into one independent variance (the marginal likelihood of the
  Hilbert-space discrepancy takes one). A subset of the runs can only raise
  the variance, so that part errs on the wide side; calibrate reports how
  far each point's variance, at posterior draws of theta, lies from the one
  used.
"""

from __future__ import annotations

import json
import logging
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy import linalg, optimize
from scipy.spatial import cKDTree

from stancal.problem.run_replicates import group_settings

logger = logging.getLogger("stancal")

SUBSET_SIZE = 1000  # runs for the hyperparameters: the mode moves little beyond it
STARTS = 3  # L-BFGS runs: a sensible start and random ones (the likelihood can have several modes)
JITTER = 1e-6  # times the emulator's variance, as functions/scaling.stan's add_jitter
MEAN_TOLERANCE = 1e-3  # Nystroem error of the emulator mean, standardised output units
MAX_GRID = 3000  # interpolation nodes over the theta box at most
NEIGHBOURS = 60  # runs in each point's local GP for the variance
LANDMARKS = 600  # points of the Nystroem approximation of the error's covariance
MAX_ERROR_RANK = 40  # the error's eigenvectors kept: each costs a basis function per gradient
ERROR_RANK_SHARE = 0.03  # keep eigenvalues above this share of the data's residual variance


@dataclass
class Hyperparameters:
    mean: float
    sd: float
    length_scale: np.ndarray  # inputs, then theta; unit-cube units
    nugget: float

    def as_stan(self) -> dict:
        return {"emulator_mean": self.mean, "emulator_sd": self.sd,
                "emulator_length_scale": self.length_scale.tolist(), "emulator_nugget": self.nugget}

    @classmethod
    def from_stan(cls, values: dict) -> Hyperparameters:
        return cls(float(values["emulator_mean"]), float(values["emulator_sd"]),
                   np.asarray(values["emulator_length_scale"], float), float(values["emulator_nugget"]))


def se_correlation(a: np.ndarray, b: np.ndarray, length_scale: np.ndarray) -> np.ndarray:
    """exp(-|(a - b) / l|^2 / 2) between the rows of a and b."""
    a, b = a / length_scale, b / length_scale
    sq = (a**2).sum(1)[:, None] + (b**2).sum(1)[None, :] - 2 * a @ b.T
    return np.exp(-0.5 * np.maximum(sq, 0.0))


def same_point(points: np.ndarray) -> np.ndarray:
    """(n, n) boolean: True where two of the n points are identical, so they
    share one draw of the emulator's nugget (functions/same_point.stan).
    Grouped exactly, as the runs' replicates are (RunReplicates)."""
    group = group_settings(points)[1]
    return group[:, None] == group[None, :]


def shared_nugget(xt: np.ndarray, known: np.ndarray | None) -> np.ndarray | None:
    """Off the diagonal, where two runs with a known (intrinsic) variance are
    replicates, one setting (x, theta): they share one draw of the nugget, the
    emulator's misfit to the simulator's mean (functions/same_point.stan's
    replicated_runs; stochastic kriging, Ankenman, Nelson & Staum 2010). None
    where no two runs share one (a deterministic simulator's runs keep the
    nugget each on its own)."""
    if known is None:
        return None
    stochastic = np.asarray(known, float) > 0
    shared = same_point(xt) & stochastic[:, None] & stochastic[None, :]
    np.fill_diagonal(shared, False)
    return shared if shared.any() else None


def run_covariance(xt: np.ndarray, h: Hyperparameters, known: np.ndarray | None = None) -> np.ndarray:
    """emulator_run_cov of functions/gp_kernels.stan (squared exponential);
    ``known``: each run's own known variance on the diagonal too (a stochastic
    simulator's intrinsic variance: stochastic kriging, Ankenman, Nelson &
    Staum 2010), as emulator.stan's run_intrinsic_sd, its replicates sharing
    one nugget (shared_nugget)."""
    K = h.sd**2 * se_correlation(xt, xt, h.length_scale)
    add_run_nugget(K, xt, h.nugget, known, JITTER * h.sd**2)
    return K


def add_run_nugget(K: np.ndarray, xt: np.ndarray, nugget: float, known: np.ndarray | None,
                   jitter: float = 0.0) -> np.ndarray | None:
    """Adds to the runs' kernel matrix K, in place, what emulator.stan adds:
    each run's nugget^2, jitter and known (intrinsic) variance on the
    diagonal, and nugget^2 between a stochastic simulator's replicates, which
    share one draw of it (shared_nugget). Returns that pattern (None: none)."""
    K[np.diag_indices_from(K)] += nugget**2 + jitter + (0.0 if known is None else known)
    shared = shared_nugget(xt, known)
    if shared is not None:
        K[shared] += nugget**2
    return shared


def run_nugget_variance(h: Hyperparameters) -> float:
    """What each run adds on the diagonal: its nugget and the jitter (add_jitter)."""
    return h.nugget**2 + JITTER * h.sd**2


def unpack(u: np.ndarray) -> Hyperparameters:
    """Hyperparameters from negative_log_posterior's vector (mean, log sd, log length scales, log nugget)."""
    return Hyperparameters(u[0], math.exp(u[1]), np.exp(u[2:-1]), math.exp(u[-1]))


def pack(h: Hyperparameters) -> np.ndarray:
    """unpack's inverse (a zero nugget kept just above 0, for its log)."""
    return np.concatenate([[h.mean, np.log(h.sd)], np.log(h.length_scale), [np.log(max(h.nugget, 1e-8))]])


def negative_log_posterior(u: np.ndarray, xt: np.ndarray, y: np.ndarray,
                           known: np.ndarray | None = None) -> tuple[float, np.ndarray]:
    """emulator.stan's log density on the unconstrained scale (with the
    Jacobian, as Stan's optimiser with jacobian=True sees it), negated, and
    its gradient; u = (mean, log sd, log length scales, log nugget);
    ``known``: each run's known variance on the diagonal (run_covariance)."""
    h = unpack(u)
    correlation = se_correlation(xt, xt, h.length_scale)
    K = h.sd**2 * correlation
    shared = add_run_nugget(K, xt, h.nugget, known, JITTER * h.sd**2)
    try:
        factor = linalg.cho_factor(K, lower=True)
    except linalg.LinAlgError:
        return np.inf, np.zeros_like(u)
    resid = y - h.mean
    alpha = linalg.cho_solve(factor, resid)
    log_det = 2 * np.log(np.diag(factor[0])).sum()
    log_lik = -0.5 * resid @ alpha - 0.5 * log_det - 0.5 * len(y) * math.log(2 * math.pi)
    ell = h.length_scale
    log_prior = (-0.5 * h.mean**2 - 0.5 * h.sd**2 + (-3 * np.log(ell) - 1 / ell).sum()
                 - 0.5 * (h.nugget / 0.05) ** 2)
    log_jacobian = u[1] + u[2:-1].sum() + u[-1]
    # d log_lik / d K = (alpha alpha' - K^-1) / 2
    W = np.outer(alpha, alpha) - linalg.cho_solve(factor, np.eye(len(y)))
    grad = np.empty_like(u)
    grad[0] = alpha.sum() - h.mean
    diagonal_sd = JITTER * h.sd**2
    grad[1] = 0.5 * (W * (2 * h.sd**2 * correlation)).sum() + np.trace(W) * diagonal_sd - h.sd**2 + 1
    weighted = W * h.sd**2 * correlation
    for d in range(len(ell)):
        sq = (xt[:, d, None] - xt[None, :, d]) ** 2 / ell[d] ** 2
        grad[2 + d] = 0.5 * (weighted * sq).sum() - 3 + 1 / ell[d] + 1
    nugget_spread = np.trace(W) + (0.0 if shared is None else W[shared].sum())  # the nugget's pattern in K
    grad[-1] = nugget_spread * h.nugget**2 - (h.nugget / 0.05) ** 2 + 1
    return -(log_lik + log_prior + log_jacobian), -grad


def fit_hyperparameters(xt: np.ndarray, y: np.ndarray, seed: int, subset: int = SUBSET_SIZE,
                        known: np.ndarray | None = None) -> tuple[Hyperparameters, int]:
    """The posterior mode of emulator.stan on a random subset of at most
    ``subset`` runs: the best of STARTS L-BFGS runs. Returns it and the
    number of runs used. ``known``: each run's known variance (run_covariance)."""
    rng = np.random.default_rng(seed)
    chosen = rng.choice(len(y), size=min(subset, len(y)), replace=False)
    xt_sub, y_sub = xt[chosen], y[chosen]
    known_sub = None if known is None else np.asarray(known, float)[chosen]
    n_ell = xt.shape[1]
    sensible = np.concatenate([[y_sub.mean(), math.log(max(y_sub.std(), 0.1))],
                               np.full(n_ell, math.log(0.5)), [math.log(0.01)]])
    starts = [sensible] + [rng.uniform(-2, 2, n_ell + 3) for _ in range(STARTS - 1)]
    best = None
    for start in starts:
        found = optimize.minimize(negative_log_posterior, start, args=(xt_sub, y_sub, known_sub), jac=True,
                                  method="L-BFGS-B", options={"maxiter": 500})
        if np.isfinite(found.fun) and (best is None or found.fun < best.fun):
            best = found
    if best is None:
        raise RuntimeError("stage 1: the emulator's marginal likelihood could not be optimised "
                           "from any start (the runs' covariance is not positive definite)")
    return unpack(best.x), len(chosen)


def whitener(factor: tuple[np.ndarray, bool]) -> np.ndarray:
    """L^-1 for a lower Cholesky factor from run_factor: then k' K^-1 k =
    |L^-1 k|^2, a matrix product for many points (faster than two
    triangular solves per call)."""
    lower = np.tril(factor[0])
    return linalg.solve_triangular(lower, np.eye(len(lower)), lower=True)


def predictive_mean_variance(points: np.ndarray, xt_runs: np.ndarray, alpha: np.ndarray, h: Hyperparameters,
                             inverse_factor: np.ndarray, block: int = 4000) -> tuple[np.ndarray, np.ndarray]:
    """The exact GP's predictive mean and variance at ``points`` given all
    runs (Rasmussen & Williams 2006, eq. 2.25-2.26), no nugget at the points
    (the simulator is deterministic there), for alpha = K^-1 (y - m) and the
    ``inverse_factor`` (``whitener``) of run_covariance; a block of points at a time."""
    mean, variance = np.empty(len(points)), np.empty(len(points))
    for start in range(0, len(points), block):
        cross = h.sd**2 * se_correlation(points[start : start + block], xt_runs, h.length_scale)
        mean[start : start + block] = h.mean + cross @ alpha
        variance[start : start + block] = h.sd**2 - np.sum((cross @ inverse_factor.T) ** 2, axis=1)
    return mean, np.maximum(variance, 0.0)


def run_factor(xt: np.ndarray, h: Hyperparameters, known: np.ndarray | None = None) -> tuple[np.ndarray, bool]:
    """The Cholesky factor of the runs' covariance, the N x N factorisation
    (in place: at N = 5,000 a copy is 200 MB); made for the mean's weights
    and again for the error basis, never per gradient."""
    return linalg.cho_factor(run_covariance(xt, h, known), lower=True, overwrite_a=True)


def chebyshev_basis(theta_unit: np.ndarray, degrees: tuple[int, ...]) -> np.ndarray:
    """chebyshev_tensor_basis of functions/chebyshev.stan: (T, Q) points of the
    unit cube -> (T, G), products of T_0..T_degree in 2 theta - 1 per
    parameter, the first parameter's index varying slowest."""
    out = np.ones((len(theta_unit), 1))
    for q, degree in enumerate(degrees):
        s = 2 * np.asarray(theta_unit)[:, q] - 1
        T = np.polynomial.chebyshev.chebvander(s, degree)  # (T, degree + 1)
        out = (out[:, :, None] * T[:, None, :]).reshape(len(s), -1)
    return out


def chebyshev_nodes(degree: int) -> np.ndarray:
    """Chebyshev extrema on [0, 1]: interpolation there converges
    exponentially for a smooth function and is well conditioned."""
    return (1 - np.cos(np.pi * np.arange(degree + 1) / degree)) / 2 if degree else np.array([0.5])


@dataclass
class ThetaInterpolant:
    """The emulator mean at fixed points as a polynomial in theta:
    mean_i(theta) = m + weights[i] . chebyshev_basis(theta, degrees), the
    weights interpolating the exact GP mean at the tensor Chebyshev nodes."""

    degrees: tuple[int, ...]
    max_error: float  # against the exact GP mean at random theta, standardised units

    def nodes(self) -> np.ndarray:
        axes = [chebyshev_nodes(p) for p in self.degrees]
        return np.array(np.meshgrid(*axes, indexing="ij")).reshape(len(axes), -1).T

    def weights(self, exact_mean_at: Callable[[np.ndarray], np.ndarray]) -> np.ndarray:
        """From the exact mean's values (points, nodes) at the nodes to the
        Chebyshev coefficients (points, G), one parameter at a time."""
        values = exact_mean_at(self.nodes())
        shape = [p + 1 for p in self.degrees]
        coefficients = values.reshape(len(values), *shape)
        for q, p in enumerate(self.degrees):  # values -> coefficients along parameter q
            to_coefficients = np.linalg.inv(np.polynomial.chebyshev.chebvander(2 * chebyshev_nodes(p) - 1, p))
            coefficients = np.moveaxis(np.tensordot(to_coefficients, coefficients, axes=([1], [q + 1])), 0, q + 1)
        return coefficients.reshape(len(values), -1)


def exact_mean(x_unit: np.ndarray, x_runs: np.ndarray, theta_runs: np.ndarray, alpha: np.ndarray,
               h: Hyperparameters, theta_unit: np.ndarray) -> np.ndarray:
    """The GP mean minus m at every (x_i, theta_t): (points, thetas)."""
    D = x_runs.shape[1]
    Kx = se_correlation(x_unit, x_runs, h.length_scale[:D])
    return Kx @ (h.sd**2 * alpha[:, None] * se_correlation(theta_runs, theta_unit, h.length_scale[D:]))


def theta_interpolant(x_runs: np.ndarray, theta_runs: np.ndarray, alpha: np.ndarray, h: Hyperparameters,
                      x_check: np.ndarray, seed: int) -> ThetaInterpolant:
    """The lowest degrees whose interpolant of the mean at ``x_check`` is
    within MEAN_TOLERANCE of the exact GP mean at random theta; each
    parameter's degree grows with 1 / its length scale."""
    D = x_runs.shape[1]
    tests = np.random.default_rng(seed).uniform(0, 1, (16, theta_runs.shape[1]))
    exact = exact_mean(x_check, x_runs, theta_runs, alpha, h, tests)
    resolution = 1.0
    while True:
        degrees = tuple(int(np.ceil(resolution * (2 + 1.5 / ell))) for ell in h.length_scale[D:])
        interpolant = ThetaInterpolant(degrees, float("nan"))
        weights = interpolant.weights(lambda nodes: exact_mean(x_check, x_runs, theta_runs, alpha, h, nodes))
        error = float(np.abs(weights @ chebyshev_basis(tests, degrees).T - exact).max())
        finer = tuple(int(np.ceil(1.4 * resolution * (2 + 1.5 / ell))) for ell in h.length_scale[D:])
        if error <= MEAN_TOLERANCE or np.prod([p + 1 for p in finer]) > MAX_GRID:
            if error > MEAN_TOLERANCE:
                logger.warning("stage 1: the emulator mean's interpolation in theta stops at degrees %s "
                               "with an error of %.2g (standardised units; target %.0e)", degrees, error,
                               MEAN_TOLERANCE)
            return ThetaInterpolant(degrees, error)
        resolution *= 1.4


def least_squares_theta(weights: np.ndarray, degrees: tuple[int, ...], mean: float, y: np.ndarray) -> np.ndarray:
    """theta (unit cube) whose emulator mean fits y best in least squares,
    the best of L-BFGS runs from a 3^Q grid of starts: where the emulator's
    variance is taken (its spread over the posterior is checked after the fit)."""
    def loss(theta: np.ndarray) -> float:
        return float(np.sum((y - mean - weights @ chebyshev_basis(theta[None, :], degrees)[0]) ** 2))

    starts = np.array(np.meshgrid(*[[0.2, 0.5, 0.8]] * len(degrees), indexing="ij")).reshape(len(degrees), -1).T
    fits = [optimize.minimize(loss, start, method="L-BFGS-B", bounds=[(0, 1)] * len(degrees)) for start in starts]
    return min(fits, key=lambda f: f.fun).x


def local_variance(x_unit: np.ndarray, theta_unit: np.ndarray, xt_runs: np.ndarray,
                   h: Hyperparameters, known: np.ndarray | None = None) -> np.ndarray:
    """The emulator's predictive variance at (x_i, theta), each from a local
    GP on the NEIGHBOURS nearest runs in the kernel's metric (no nugget at the
    points; a stochastic simulator's intrinsic variance, ``known`` per run,
    is on the runs' diagonal only: the emulator is of its mean)."""
    points = np.column_stack([x_unit, np.broadcast_to(theta_unit, (len(x_unit), len(theta_unit)))])
    k = min(NEIGHBOURS, len(xt_runs))
    _, nearest = cKDTree(xt_runs / h.length_scale).query(points / h.length_scale, k=k)
    nearest = nearest.reshape(len(points), k)
    variance = np.empty(len(points))
    for i, rows in enumerate(nearest):
        local = xt_runs[rows]
        cross = h.sd**2 * se_correlation(points[i : i + 1], local, h.length_scale)[0]
        factor = linalg.cho_factor(run_covariance(local, h, None if known is None else known[rows]), lower=True)
        variance[i] = h.sd**2 - cross @ linalg.cho_solve(factor, cross)
    return np.maximum(variance, 0.0)


@dataclass
class ErrorBasis:
    """The emulator's error at the points, e ~ N(0, C) with
    C ~ columns columns' + diag(residual_variance)."""

    columns: np.ndarray  # (points, rank): eigenvectors times sqrt(eigenvalue)
    residual_variance: np.ndarray  # (points,): what the columns leave of each point's variance
    rank_capped: bool  # eigenvalues above the threshold were left to the independent part


def error_basis(x_unit: np.ndarray, theta_unit: np.ndarray, xt_runs: np.ndarray, h: Hyperparameters,
                threshold: float, known: np.ndarray | None = None) -> ErrorBasis:
    """The leading eigenvectors of the emulator's predictive covariance at
    (x_i, theta), C = k(P, P) - k(P, runs) K^-1 k(runs, P), whose
    eigenvalues exceed ``threshold``: C's Nystroem approximation through
    at most LANDMARKS of the points, C ~ C(P, L) C(L, L)^+ C(L, P), reduced
    by an SVD. Each point's residual is its local-GP variance minus what the
    columns explain (the Nystroem part is at most the exact variance, the
    local one at least it). C carries the emulator's nugget, its misfit
    (as modular.stan's nugget_obs: Higdon et al. 2008), nugget^2 S with
    S_ij = 1 where two points are one: at every point on the residual, and
    the part groups of identical points share, nugget^2 G G' (G: one
    indicator column per group of two or more; none at distinct points),
    exactly, as columns beside the Nystroem ones before the SVD (every group
    shares it, a landmark among it or not; its cost grows with the groups)."""
    points = np.column_stack([x_unit, np.broadcast_to(theta_unit, (len(x_unit), len(theta_unit)))])
    rng = np.random.default_rng(0)
    landmarks = (np.arange(len(points)) if len(points) <= LANDMARKS
                 else np.sort(rng.choice(len(points), LANDMARKS, replace=False)))
    # made again rather than kept: PyStan forks its sampling workers from this process, and
    # a factor held here (200 MB at N = 5,000) would sit in each of them
    runs_solve = linalg.cho_solve(run_factor(xt_runs, h, known),
                                  h.sd**2 * se_correlation(xt_runs, points[landmarks], h.length_scale))
    to_landmarks = np.empty((len(points), len(landmarks)))
    for start in range(0, len(points), 1000):  # k(P, runs) a block of points at a time
        block = points[start : start + 1000]
        to_landmarks[start : start + 1000] = h.sd**2 * (
            se_correlation(block, points[landmarks], h.length_scale)
            - se_correlation(block, xt_runs, h.length_scale) @ runs_solve)
    eigenvalues, eigenvectors = np.linalg.eigh(to_landmarks[landmarks])
    kept = eigenvalues > 1e-10 * max(eigenvalues.max(), 1e-300)
    half = to_landmarks @ (eigenvectors[:, kept] / np.sqrt(eigenvalues[kept]))  # C ~ half half'
    half = np.hstack([half, h.nugget * identical_groups(points)])
    left, singular, _ = np.linalg.svd(half, full_matrices=False)
    above = int(np.sum(singular**2 > threshold))
    rank = min(above, MAX_ERROR_RANK)
    columns = left[:, :rank] * singular[:rank]
    local = point_variance(x_unit, theta_unit, xt_runs, h, known)
    return ErrorBasis(columns, np.maximum(local - (columns**2).sum(1), 0.0), above > rank)


def point_variance(x_unit: np.ndarray, theta_unit: np.ndarray, xt_runs: np.ndarray, h: Hyperparameters,
                   known: np.ndarray | None) -> np.ndarray:
    """Each point's emulator variance: the local GP's, and the nugget, its misfit there."""
    return local_variance(x_unit, theta_unit, xt_runs, h, known) + h.nugget**2


def identical_groups(points: np.ndarray) -> np.ndarray:
    """(points, groups): one indicator column per group of two or more
    identical points (same_point's groups; none where all are distinct)."""
    _, group, counts = group_settings(points)
    shared = np.flatnonzero(counts > 1)
    return (group[:, None] == shared[None, :]).astype(float)


@dataclass
class ScalableEmulator:
    """The fixed stage-1 emulator of modular_hsgp.stan: what it needs from
    all the runs, computed once per emulator (``of`` keeps the last one)."""

    hyperparameters: Hyperparameters
    x_runs: np.ndarray  # (N, D), unit cube
    theta_runs: np.ndarray  # (N, Q), unit cube
    alpha: np.ndarray  # K^-1 (y - m)
    interpolant: ThetaInterpolant
    known: np.ndarray | None = None  # (N,): a stochastic simulator's intrinsic variance at each run

    @property
    def xt_runs(self) -> np.ndarray:
        return np.column_stack([self.x_runs, self.theta_runs])

    @classmethod
    def fit(cls, x_runs: np.ndarray, theta_runs: np.ndarray, y_runs: np.ndarray, x_points: np.ndarray,
            seed: int, known: np.ndarray | None = None) -> tuple[ScalableEmulator, dict]:
        """Stage 1: hyperparameters, weights and the theta interpolant
        (checked at the physical points ``x_points``). Returns it and what to
        keep of it (``emulator`` of the result: enough to rebuild it with ``of``)."""
        h, used = fit_hyperparameters(np.column_stack([x_runs, theta_runs]), y_runs, seed, known=known)
        alpha = linalg.cho_solve(run_factor(np.column_stack([x_runs, theta_runs]), h, known), y_runs - h.mean)
        check = x_points[np.random.default_rng(seed).choice(len(x_points), min(500, len(x_points)), replace=False)]
        interpolant = theta_interpolant(x_runs, theta_runs, alpha, h, check, seed)
        stored = {**h.as_stan(), "theta_degrees": list(interpolant.degrees)}
        _BUILT.clear()  # one emulator's arrays at a time
        key = _key(x_runs, theta_runs, y_runs, stored, known)
        _BUILT[key] = cls(h, x_runs, theta_runs, alpha, interpolant, known)
        return _BUILT[key], {
            "hyperparameters": stored, "hyperparameter_runs": used,
            "theta_interpolation_points": int(np.prod([p + 1 for p in interpolant.degrees])),
            "theta_interpolation_error": interpolant.max_error}

    @classmethod
    def of(cls, x_runs: np.ndarray, theta_runs: np.ndarray, y_runs: np.ndarray,
           stored: dict, known: np.ndarray | None = None) -> ScalableEmulator:
        """The emulator ``fit`` described with ``stored`` (no optimisation)."""
        key = _key(x_runs, theta_runs, y_runs, stored, known)
        if key not in _BUILT:
            h = Hyperparameters.from_stan(stored)
            alpha = linalg.cho_solve(run_factor(np.column_stack([x_runs, theta_runs]), h, known), y_runs - h.mean)
            _BUILT.clear()
            _BUILT[key] = cls(h, x_runs, theta_runs, alpha,
                              ThetaInterpolant(tuple(stored["theta_degrees"]), float("nan")), known)
        return _BUILT[key]

    def mean_weights(self, x_unit: np.ndarray) -> np.ndarray:
        """(points, G): the emulator mean's weights at the points."""
        return self.interpolant.weights(lambda nodes: exact_mean(
            x_unit, self.x_runs, self.theta_runs, self.alpha, self.hyperparameters, nodes))

    def variance(self, x_unit: np.ndarray, theta_unit: np.ndarray) -> np.ndarray:
        """Each point's emulator variance: the local GP's, and the nugget, its misfit there (error_basis)."""
        return point_variance(x_unit, theta_unit, self.xt_runs, self.hyperparameters, self.known)

    def error_basis(self, x_unit: np.ndarray, theta_unit: np.ndarray, threshold: float) -> ErrorBasis:
        return error_basis(x_unit, theta_unit, self.xt_runs, self.hyperparameters, threshold, self.known)


_BUILT: dict[tuple, ScalableEmulator] = {}


def _key(x_runs: np.ndarray, theta_runs: np.ndarray, y_runs: np.ndarray, stored: dict,
         known: np.ndarray | None) -> tuple:
    """What defines an emulator: the runs, hyperparameters and degrees (not
    calibrate's variance_theta and error_threshold, added later: the N x N
    factor is not redone)."""
    defining = {k: v for k, v in stored.items() if k not in ("variance_theta", "error_threshold",
                                                               "intrinsic_variance")}
    return (hash(np.asarray(x_runs).tobytes()), hash(np.asarray(theta_runs).tobytes()),
            hash(np.asarray(y_runs).tobytes()), json.dumps(defining, sort_keys=True),
            None if known is None else hash(np.asarray(known, float).tobytes()))
