"""Predictions of a calibration at new points: the program's generated
quantities rerun at the posterior draws (zeta, f(x, theta), delta), and new
observations drawn from the likelihood."""

from __future__ import annotations

import numpy as np
import pandas as pd

from stancal.fitting.l2 import reproject
from stancal.problem.codes import Likelihood
from stancal.problem.noise import HETEROSCEDASTIC, PER_SOURCE, draw_noise, row_noise_sd, with_known_sd
from stancal.results.result import BIAS_NEW, NEW_OBSERVATION, PREDICTED, interval_table
from stancal.stan.backends import get_backend
from stancal.stan.standata import build_stan_data, to_stan_json


def predict(result, new_points: pd.DataFrame | None = None, *, backend: str | None = None,
            seed: int = 1, max_draws: int | None = None) -> pd.DataFrame:
    """zeta (the real process), f(x, theta) and delta at ``new_points``
    (columns: simulator inputs and covariates), with 5/50/95 % quantiles,
    plus ``y`` with measurement noise. Without ``new_points``, the points
    stored with the fit. ``max_draws``: at new points, use every k-th draw
    of each chain, at most this many in all (a figure's bands need a few
    hundred; generated quantities cost a Stan call per draw)."""
    step = 1  # every draw of each chain
    if new_points is None:
        draws = {k: np.asarray(v) for k, v in result.idata["predictions"].data_vars.items()}
        points = result.idata["predictions_constant_data"].to_dataset().to_dataframe()
        points = points.reset_index(drop=True)
    else:
        points = new_points.reset_index(drop=True)
        stan_data = build_stan_data(result.data, result.row.data, result.options, points,
                                    emulator_hyperparameters=result.emulator.get("hyperparameters"))
        params = {k: np.asarray(v) for k, v in result.idata["stan_parameters"].data_vars.items()}
        if max_draws is not None:
            chains, size = next(iter(params.values())).shape[:2]
            step = -(-chains * size // max_draws)
        params = {k: v[:, ::step] for k, v in params.items()}
        draws = get_backend(backend or result.backend).generate_quantities(
            result.program, to_stan_json(stan_data), params, seed)
        if result.l2:
            draws = reproject(result, points, draws, step)
    table = points.copy()
    for name in PREDICTED:
        values = draws[name].reshape(-1, len(points))
        table = table.assign(**interval_table(values, name.removesuffix("_new")))
    biases = result.source_biases(draws[BIAS_NEW], len(points)) if result.options.biased_sources else {}
    for name, values in biases.items():
        table = table.assign(**interval_table(values, f"bias_{name}"))
    if new_points is None and NEW_OBSERVATION in draws:  # drawn by the sampler's own RNG
        new_y = draws[NEW_OBSERVATION].reshape(-1, len(points))
    else:  # PyStan reruns generated quantities with one fixed RNG seed: draw the noise here
        zeta = draws["zeta_new"].reshape(-1, len(points)) + result.reading_bias(points, biases)
        new_y = _observe(result, zeta, points, seed, step)
    return table.assign(**interval_table(new_y, "y"))


def _observe(result, zeta: np.ndarray, points: pd.DataFrame, seed: int, step: int = 1) -> np.ndarray:
    """New observations given draws (samples, points) of the mean response,
    at every ``step``-th posterior draw of each chain."""
    rng = np.random.default_rng(seed)
    likelihood = result.data.observations.likelihood
    posterior = result.idata["posterior"].isel(draw=slice(None, None, step))
    if likelihood is Likelihood.POISSON:
        return rng.poisson(zeta).astype(float)
    if likelihood is Likelihood.NEGBINOMIAL:
        phi = np.asarray(posterior["phi"]).reshape(-1, 1)
        return rng.negative_binomial(phi, phi / (phi + zeta)).astype(float)
    if likelihood is Likelihood.BINOMIAL:
        return rng.binomial(result.data.trials_at(points), zeta).astype(float)
    return zeta + _noise(result, posterior, points, rng, len(zeta), step)


def _noise(result, posterior, points: pd.DataFrame, rng: np.random.Generator, draws: int,
           step: int) -> np.ndarray:
    """Measurement noise at the points with the fit's noise model
    (stancal.problem.noise): a point's source and known sd where the points
    give those columns; without a source, per source noise is that of a
    source drawn in the physical rows' shares; Student-t with each draw's nu;
    heteroscedastic: the sd at the points from its log sd GP, one draw of
    the GP's conditional per posterior draw (CalibrationResult.noise_sd_at)."""
    noise = result.data.noise
    source, known = noise.at(points)
    if result.options.noise != PER_SOURCE:  # one sd for every source (a source column for biased sources)
        source = None
    if result.options.noise == HETEROSCEDASTIC:
        scale = with_known_sd(result.noise_sd_at(points, rng, step), known)
        return draw_noise(rng, scale, None)
    shares = noise.rows_per_source / len(noise.source_index)
    scale = row_noise_sd(np.asarray(posterior["noise_sd"]).reshape(draws, -1), source, known, shares, rng)
    return draw_noise(rng, scale, np.asarray(posterior["nu"]).ravel() if "nu" in posterior else None)
