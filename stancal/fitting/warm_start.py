"""Refits that start where the full-data fit ended. A refit without a few
rows (the gap diagnosis's exact LOO refits, as the loo package's reloo makes
them, Vehtari, Gelman & Gabry 2017; or K-fold's folds) targets a posterior
close to the full-data one, so its chains can start from the full fit's
draws, with its adapted step size and inverse metric, and need a short
warm-up rather than a climb from Stan's random inits to the typical set and
a fresh adaptation. The warm-up keeps Stan's three adaptation stages (Stan
Reference Manual, "HMC algorithm parameters": a fast first buffer, slow
metric windows, a fast final buffer; Hoffman & Gelman 2014 for the step
size's dual averaging), shortened (stancal.stan.backends.base.warm_windows)."""

from __future__ import annotations

from typing import Any

import numpy as np

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
    parameters = result.idata["stan_parameters"]
    rows = len(result.data.physical)
    rng = np.random.default_rng(seed)
    full_chains, draws = (parameters.sizes["chain"], parameters.sizes["draw"])
    picks = [(c % full_chains, int(rng.integers(draws))) for c in range(chains)]
    inits = [_point(parameters, chain, draw, rows, train) for chain, draw in picks]
    step_size = float(np.median(np.asarray(result.idata["sample_stats"]["step_size"])))
    return WarmStart(inits, step_size, _inv_metric(result, picks, rows, parameters))


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
