"""Refits that start where the full-data fit ended. A refit without a few
rows (the gap diagnosis's exact LOO refits, as the loo package's reloo makes
them, Vehtari, Gelman & Gabry 2017; or K-fold's folds) targets a posterior
close to the full-data one, so its chains can start from the full fit's
draws, with its adapted step size and inverse metric, and need a short
warm-up rather than a climb from Stan's random inits to the typical set and
a fresh adaptation. A candidate of the gap diagnosis (the baseline's model
plus one mean term, or its simulator variant with a parameter or input
more) starts from the baseline's draws the same way: its shared parameters
near where they will end, its own at random, with a warm-up long enough to
adapt to the term the baseline lacked. The warm-up keeps Stan's three adaptation stages (Stan
Reference Manual, "HMC algorithm parameters": a fast first buffer, slow
metric windows, a fast final buffer; Hoffman & Gelman 2014 for the step
size's dual averaging), shortened (stancal.stan.backends.base.warm_windows)."""

from __future__ import annotations

from typing import Any

import numpy as np

from stancal.fitting.inits import theta_unit_init
from stancal.results.result import CalibrationResult
from stancal.stan.backends import WarmStart

# the refit's warm-up: this fraction of the full fit's, at least REFIT_WARMUP_LEAST (never more than the full
# fit's). 200 of 1000 leaves a 125-draw metric window (base.warm_windows): enough for the diagonal metric
# of these programs, whose posteriors barely move when a point is held out
REFIT_WARMUP_FRACTION = 0.2
REFIT_WARMUP_LEAST = 150
# and its draws: a refit's only output is the held-out density of a few points, a mean over draws whose Monte
# Carlo error at 4 x 500 draws is far below the se of any ELPD difference; its generated quantities (the
# exact conditional log likelihood, predictions) cost as much per draw as a transition does
REFIT_DRAWS_FRACTION = 0.5
REFIT_DRAWS_LEAST = 500


# a candidate's warm-up: longer than a refit's, as its own parameters start at random and its posterior moves
# more (a variant's parameter can shift theta); 500 of 1000 leaves a 388-draw metric window
CANDIDATE_WARMUP_FRACTION = 0.5
CANDIDATE_WARMUP_LEAST = 250


def refit_warmup(warmup: int) -> int:
    """A warm-started refit's warm-up iterations, given the full fit's."""
    return min(warmup, max(REFIT_WARMUP_LEAST, round(REFIT_WARMUP_FRACTION * warmup)))


def refit_draws(draws: int) -> int:
    """A warm-started refit's draws per chain, given the full fit's."""
    return min(draws, max(REFIT_DRAWS_LEAST, round(REFIT_DRAWS_FRACTION * draws)))


def warm_start(result: CalibrationResult, train: np.ndarray, chains: int, seed: int) -> WarmStart:
    """Where a refit on the rows ``train`` of the full fit's data starts:
    each chain at a random draw of its own full-fit chain (the chains start
    apart, so R-hat still means something), the median adapted step size,
    and the inverse metric when the backend reported it. A parameter with one
    value per data row (a latent GP's standard normals) keeps the training
    rows' values; one with a row axis among others is left to Stan's inits."""
    return _start(result, train, chains, np.random.default_rng(seed))


def _start(result: CalibrationResult, train: np.ndarray, chains: int, rng: np.random.Generator,
           extra=lambda chain, draw: {}, related: bool = False) -> WarmStart:
    """Each chain at a random draw of its own chain of ``result`` (its point
    updated by ``extra(chain, draw)``), the median step size and the metric."""
    parameters = result.idata["stan_parameters"]
    rows = len(result.data.physical)
    full_chains, draws = (parameters.sizes["chain"], parameters.sizes["draw"])
    picks = [(c % full_chains, int(rng.integers(draws))) for c in range(chains)]
    inits = [_point(parameters, chain, draw, rows, train) | extra(chain, draw) for chain, draw in picks]
    step_size = float(np.median(np.asarray(result.idata["sample_stats"]["step_size"])))
    return WarmStart(inits, step_size, _inv_metric(result, picks, rows, parameters), related)


def _point(parameters, chain: int, draw: int, rows: int, train: np.ndarray) -> dict[str, Any]:
    point: dict[str, Any] = {}
    for name, variable in parameters.data_vars.items():
        value = np.asarray(variable[chain, draw])
        if value.size == 0:  # an option switched off (array[0]): nothing to start
            continue
        if value.ndim == 1 and len(value) == rows:
            point[name] = value[train].tolist()
        elif rows not in value.shape:
            point[name] = value.tolist()
    return point


def _inv_metric(result: CalibrationResult, picks: list[tuple[int, int]], rows: int,
                parameters) -> np.ndarray | None:
    """The full fit's inverse metric per refit chain, when the backend
    reported it and the unconstrained space keeps its size (no parameter per
    data row: else which entries to drop would depend on the program's
    layout)."""
    if "adaptation" not in result.idata.children:
        return None
    if any(rows in variable.shape[2:] for variable in parameters.data_vars.values()):
        return None
    metric = np.asarray(result.idata["adaptation"]["inv_metric"])
    return np.stack([metric[chain] for chain, _ in picks])


def warm_refit_options(result: CalibrationResult, train: np.ndarray, sampling: dict[str, Any],
                       seed: int) -> dict[str, Any]:
    """calibrate()'s keywords for a warm-started refit on the rows ``train``."""
    chains, warmup, draws = (sampling.get(k, default) for k, default in
                             (("chains", 4), ("warmup", 1000), ("draws", 1000)))
    return {"warm_start": warm_start(result, train, chains, seed), "warmup": refit_warmup(warmup),
            "draws": refit_draws(draws)}


def candidate_warmup(warmup: int) -> int:
    """A warm-started candidate fit's warm-up iterations, given the baseline's."""
    return min(warmup, max(CANDIDATE_WARMUP_LEAST, round(CANDIDATE_WARMUP_FRACTION * warmup)))


def candidate_start(baseline: CalibrationResult, bounds: dict[str, tuple[float, float]], chains: int,
                    seed: int) -> WarmStart:
    """Where a candidate's fit starts: each chain at a random draw of its own
    baseline chain, theta by name (``bounds``: the candidate's, in its
    order; a variant's own parameter starts at random in the middle of its
    range), the baseline's other parameters as they were (those the
    candidate has in another shape are dropped when it is sampled:
    WarmStart.fitted), and the baseline's median step size and metric."""
    theta = np.asarray(baseline.idata["posterior"]["theta"])  # chain, draw, parameter
    rng = np.random.default_rng(seed)

    def by_name(chain: int, draw: int) -> dict[str, list[float]]:
        values = dict(zip(baseline.data.theta_names, theta[chain, draw].reshape(-1), strict=False))
        return theta_unit_init(values, bounds, rng)

    return _start(baseline, np.arange(len(baseline.data.physical)), chains, rng, by_name, related=True)


def warm_candidate_options(baseline: CalibrationResult, bounds: dict[str, tuple[float, float]],
                           sampling: dict[str, Any], seed: int) -> dict[str, Any]:
    """calibrate()'s keywords for a candidate's fit started from the baseline's:
    a shorter warm-up and the baseline's draws. Half the draws (as a refit
    has) were measured on the cooling case: R-hat of noise_sd up to 1.016 and
    a tail ESS of 183 at 4 x 500, where the candidate's summaries, shown to
    the user, need the bar a calibration meets."""
    chains, warmup = (sampling.get(k, default) for k, default in (("chains", 4), ("warmup", 1000)))
    return {"warm_start": candidate_start(baseline, bounds, chains, seed), "warmup": candidate_warmup(warmup)}
