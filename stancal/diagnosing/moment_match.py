"""PSIS-LOO with moment matching: the points where Pareto smoothed importance
sampling is unreliable (Pareto k above 0.7) scored without a refit.

The full-data posterior draws, on the unconstrained scale, are moved by
affine maps until they look like draws of the leave-one-out posterior, and
importance sampling restarts from there: Paananen, Piironen, Bürkner &
Vehtari (2021), "Implicitly adaptive importance sampling", *Statistics and
Computing* 31, 16, the algorithm of the loo package's ``loo_moment_match``.
For observation i, with p the full-data posterior density and u the draws:

- each map moves the draws' moments to their importance-weighted ones: the
  mean (a shift); the mean and the marginal variances; the mean and the
  covariance (only with at least 10 draws a dimension, as loo does). A map is
  kept only when it lowers Pareto k, and the first one is tried again after
  each kept map; the search ends when k is below the limit, when no map
  lowers it, or after ``max_iters`` maps;
- the moved draws T(u) come from p pushed through T, whose density is
  p(u) / |det A| at T(u), so the log ratio to the leave-one-out target
  p(T(u)) / p(y_i | T(u)) is lp(T(u)) - lp(u) - log_lik_i(T(u)) (|det A|, a
  constant, drops out of self-normalised weights);
- "split" (the paper's section 3.3, loo's default): the final estimate
  moves half the draws only and weighs every draw against the mixture of p
  and p pushed through T, log proposal = log(p(v) + p(T^-1 v) / |det A|), so
  that the estimate stays consistent whatever T the search chose from these
  same draws.

stancal composes the kept maps exactly (T(u) = A u + b); loo keeps a
running shift, scaling and mapping instead. The log likelihood of the latent
programs integrates δ_i out (Vehtari et al. 2016, *JMLR* 17), so lp - log_lik_i
is a proper density whose (parameters, δ_-i) marginal is the leave-one-out
posterior: the method applies to them as to the Gaussian ones."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.special import logsumexp

from stancal.diagnosing.density_pool import DensityPool
from stancal.stan.backends import get_backend
from stancal.stan.standata import build_stan_data, to_stan_json

MAX_ITERS = 30  # loo's default: maps kept at most, per observation
# the gap's search for maps goes on to this Pareto k, below loo's 0.7 (the limit a point must reach to be
# scored): on tests/test_moment_match.py's regressions, over 20 seeds, the error in log p(y_i | y_-i) fell
# from 0.09-0.23 (largest 0.34-1.37) to 0.01 (largest 0.06-0.11) for 2 to 3 more maps; on the counts
# case (2 x 300 draws, 5 points) the matching took 66 s instead of 40 s
MATCH_K_TARGET = 0.3
COV_DRAWS_PER_DIMENSION = 10  # the covariance map needs this many draws per unconstrained dimension (loo's rule)


@dataclass(frozen=True)
class Target:
    """The full-data posterior, at any unconstrained draws (S, d):
    ``log_density`` gives lp (S,), as the sampler's lp__ (Jacobian included);
    ``pointwise`` gives each observation's log likelihood and held-out mean
    (both (S, N)): the program's ``log_lik`` and ``y_loo_mean``. A draw
    outside the support has lp -inf and NaN pointwise values."""

    log_density: Callable[[np.ndarray], np.ndarray]
    pointwise: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]


@dataclass(frozen=True)
class MatchedPoint:
    """One observation's moment matching: its Pareto k before and after,
    and the held-out log density and mean it gives."""

    row: int
    k_before: float
    k_after: float
    elpd: float  # log p(y_i | y_-i)
    heldout_mean: float  # E(y_i | y_-i)
    maps: int  # affine maps kept

    def to_json(self) -> dict[str, Any]:
        return {"row": self.row, "k_before": round(self.k_before, 3), "k_after": round(self.k_after, 3),
                "maps": self.maps}


def psis(log_ratios: np.ndarray, r_eff: float) -> tuple[np.ndarray, float]:
    """Pareto smoothed, normalised log weights of draws with these log
    ratios, and Pareto k (Vehtari et al. 2024, *JMLR* 25; arviz-stats's
    psislw, which takes the negated log ratios, a log likelihood)."""
    from arviz_stats.base import array_stats

    ratios = np.where(np.isnan(log_ratios), -np.inf, log_ratios)  # a draw outside the support weighs nothing
    log_weights, k = array_stats.psislw(-ratios, r_eff=r_eff)
    return np.asarray(log_weights), float(k)


@dataclass
class _State:
    """The moved draws and what importance sampling gives at them."""

    draws: np.ndarray  # (S, d): A u + b
    a: np.ndarray  # (d, d)
    b: np.ndarray  # (d,)
    log_weights: np.ndarray  # PSIS's, normalised
    k: float
    log_lik: np.ndarray  # (S,) log_lik_i at the moved draws
    mean: np.ndarray  # (S,) y_loo_mean_i there
    maps: int = 0


def _shift(draws: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The map (A, b) that moves the draws' mean to their weighted mean."""
    return np.eye(draws.shape[1]), weights @ draws - draws.mean(0)


def _shift_and_scale(draws: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The map that moves the mean and the marginal variances to their weighted ones."""
    s = len(draws)
    mean, weighted = draws.mean(0), weights @ draws
    weighted_var = (weights @ draws**2 - weighted**2) * s / (s - 1)
    scaling = np.sqrt(weighted_var / draws.var(0, ddof=1))
    return np.diag(scaling), weighted - scaling * mean


def _shift_and_cov(draws: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The map that moves the mean and the covariance to their weighted ones
    (weighted covariance unbiased as R's cov.wt); the identity for the
    covariance when the weighted one is not positive definite (as loo)."""
    mean, weighted = draws.mean(0), weights @ draws
    centred = draws - weighted
    weighted_cov = (centred.T * weights) @ centred / (1 - np.sum(weights**2))
    try:
        mapping = np.linalg.cholesky(weighted_cov) @ np.linalg.inv(np.linalg.cholesky(np.cov(draws, rowvar=False)))
    except np.linalg.LinAlgError:
        mapping = np.eye(draws.shape[1])
    return mapping, weighted - mapping @ mean


def _tried(state: _State, a: np.ndarray, b: np.ndarray, i: int, lp: np.ndarray, target: Target,
           r_eff: float) -> _State:
    """The state after moving its draws by (a, b) once more."""
    moved = state.draws @ a.T + b
    log_lik, mean = (values[:, i] for values in target.pointwise(moved))
    log_weights, k = psis(target.log_density(moved) - lp - log_lik, r_eff)
    return _State(moved, a @ state.a, a @ state.b + b, log_weights, k, log_lik, mean, state.maps + 1)


def _search(state: _State, i: int, lp: np.ndarray, target: Target, r_eff: float, *, k_target: float,
            max_iters: int, cov: bool) -> _State:
    """Keep the maps that lower Pareto k, the cheapest first, until k is at most ``k_target``."""
    maps = [_shift, _shift_and_scale, *([_shift_and_cov] if cov else [])]
    while state.k > k_target and state.maps < max_iters:
        for make in maps:
            tried = _tried(state, *make(state.draws, np.exp(state.log_weights)), i, lp, target, r_eff)
            if tried.k < state.k:
                state = tried
                break
        else:  # no map lowered k
            break
    return state


def _split(state: _State, upars: np.ndarray, i: int, target: Target,
           r_eff: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Split moment matching: the first half of the draws moved by T, the
    second kept, each weighed against the mixture of p and T's push-forward.
    Returns the log weights, log_lik_i and y_loo_mean_i at those draws."""
    half = len(upars) // 2
    draws = upars.copy()
    draws[:half] = upars[:half] @ state.a.T + state.b
    inverse = np.linalg.inv(state.a)
    pulled = draws.copy()  # T^-1 at every draw: p's push-forward density there, up to |det A|
    pulled[half:] = (upars[half:] - state.b) @ inverse.T
    pulled[:half] = upars[:half]
    lp = target.log_density(draws)
    lp_pushed = target.log_density(pulled) - np.linalg.slogdet(state.a)[1]
    log_lik, mean = (values[:, i] for values in target.pointwise(draws))
    log_weights, _ = psis(lp - np.logaddexp(lp, lp_pushed) - log_lik, r_eff)
    return log_weights, log_lik, mean


def match_point(i: int, upars: np.ndarray, lp: np.ndarray, log_lik: np.ndarray, loo_mean: np.ndarray,
                target: Target, r_eff: float, *, k_target: float = 0.7, max_iters: int = MAX_ITERS,
                split: bool = True) -> MatchedPoint:
    """Moment-matched PSIS-LOO of observation ``i``: ``upars`` (S, d) the
    full-data posterior's draws on the unconstrained scale, ``lp`` (S,) its
    log density there, ``log_lik`` and ``loo_mean`` (S, N) the program's
    pointwise values at them, ``r_eff`` the draws' relative efficiency (for
    PSIS's tail length). The search for maps ends once Pareto k is at most
    ``k_target`` (loo stops at its reliability limit, 0.7; further maps
    cost a pass over the draws each and bring the estimate closer: see
    MATCH_K_TARGET). With ``split`` (the default, as loo's) the final
    weights are split moment matching's."""
    log_weights, k = psis(-log_lik[:, i], r_eff)
    start = _State(upars, np.eye(upars.shape[1]), np.zeros(upars.shape[1]), log_weights, k, log_lik[:, i],
                   loo_mean[:, i])
    cov = len(upars) >= COV_DRAWS_PER_DIMENSION * upars.shape[1]
    state = _search(start, i, lp, target, r_eff, k_target=k_target, max_iters=max_iters, cov=cov)
    log_weights, point_log_lik, mean = state.log_weights, state.log_lik, state.mean
    if split and state.maps:
        log_weights, point_log_lik, mean = _split(state, upars, i, target, r_eff)
    finite = np.isfinite(point_log_lik)  # a draw outside the support has weight 0 (psis)
    return MatchedPoint(i, k, state.k, float(logsumexp(point_log_lik[finite] + log_weights[finite])),
                        float(np.sum(np.exp(log_weights[finite]) * mean[finite])), state.maps)


# ---- a fit's posterior as the target ------------------------------------------
LOG_LIK, LOO_MEAN = "log_lik", "y_loo_mean"  # the programs' pointwise generated quantities (stan_models/*.stan)


def fit_stan_data(result) -> dict[str, Any]:
    """The Stan data moment matching evaluates a scalar fit at: the fit's,
    without prediction points (P = 0): the pointwise values need none, and
    httpstan rebuilds the model from the data at every call."""
    return to_stan_json(build_stan_data(result.data, result.row.data, result.options, result.data.source.iloc[:0],
                                        emulator_hyperparameters=result.emulator.get("hyperparameters")))


def fit_target(result, pool: DensityPool | None = None) -> tuple[Target, np.ndarray]:
    """A scalar fit's posterior as a Target, through its backend, and its
    draws on the unconstrained scale (S, d), chains one after another. With
    a ``pool`` that has workers, the Target's passes over the draws run
    split between its processes (stancal.diagnosing.density_pool)."""
    stan_data = fit_stan_data(result)
    backend = get_backend(result.backend)
    # the quantities first: a backend without them (cmdstanpy) says so in its own words
    quantities = backend.unconstrained_quantities_function(result.program, stan_data)
    unconstrain, log_density = backend.log_density_functions(result.program, stan_data)
    spread = pool.functions(result.backend, result.program, stan_data, (LOG_LIK, LOO_MEAN)) if pool else None
    if spread is not None:
        log_density, quantities = spread

    def pointwise(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        values = quantities(points)
        return values[LOG_LIK], values[LOO_MEAN]

    parameters = {k: np.asarray(v) for k, v in result.idata["stan_parameters"].data_vars.items()}
    upars = unconstrain(parameters)
    return Target(log_density, pointwise), upars.reshape(-1, upars.shape[-1])


def relative_efficiency(result) -> float:
    """The draws' relative efficiency as arviz-stats's loo takes it (the
    mean ESS over the posterior's variables, per draw), so that Pareto k
    here is the k psis_score reported."""
    import arviz_stats  # noqa: F401  (registers the azstats accessor: match_fit may run before any loo)

    posterior = result.idata["posterior"].to_dataset()
    draws = posterior.sizes["chain"] * posterior.sizes["draw"]
    if posterior.sizes["chain"] == 1:
        return 1.0
    ess = posterior.azstats.ess(method="mean")
    return float(np.mean(np.hstack([np.ravel(ess[v].values) for v in ess.data_vars])) / draws)


def match_fit(result, rows: list[int], k_target: float = MATCH_K_TARGET,
              pool: DensityPool | None = None) -> list[MatchedPoint]:
    """Moment-matched PSIS-LOO of a scalar fit's observations ``rows``
    (those with a high Pareto k), from its stored draws, log density,
    log likelihood and held-out means; each pass over the draws split
    between the ``pool``'s processes when it has workers. Run it in a
    process's main thread: the model's log density called from a worker
    thread crashed the process."""
    target, upars = fit_target(result, pool)
    n = len(result.data.physical)
    log_lik = np.asarray(result.idata["log_likelihood"]["y"]).reshape(-1, n)
    loo_mean = np.asarray(result.idata["at_observations"][LOO_MEAN]).reshape(-1, n)
    lp = np.asarray(result.idata["sample_stats"]["lp"]).reshape(-1)  # the sampler's, at these draws (test_latent)
    r_eff = relative_efficiency(result)
    return [match_point(i, upars, lp, log_lik, loo_mean, target, r_eff, k_target=k_target)
            for i in rows]
