"""Stage 1: the emulator fitted to the simulator runs before sampling, for
the programs whose registry row names a stage 1 (modular, Liu et al. 2009;
Bayarri et al. 2007): emulator.stan's hyperparameters by optimisation, the
scalable emulator of precomputed weights, one GP per basis component of
a vector output (Higdon et al. 2008), or the multi-fidelity emulator of
several simulators' runs (Kennedy & O'Hagan 2000)."""

from __future__ import annotations

import logging
import time
from typing import Any

import numpy as np
from threadpoolctl import threadpool_limits

from stancal.fitting.run_variance import intrinsic_variance
from stancal.fitting.stage_one_theta_low import fit_theta_low_emulator
from stancal.numerics.kernels import ard_cross_cov
from stancal.numerics.multifidelity import (
    RHO_PROFILE_GRID,
    Level,
    cheap_runs_value,
    fit_levels,
    mean_function,
    rho_profile,
    rho_range,
)
from stancal.numerics.multifidelity_variance import variance_correction
from stancal.numerics.scalable_emulator import (
    ERROR_RANK_SHARE,
    NEIGHBOURS,
    Hyperparameters,
    ScalableEmulator,
    add_run_nugget,
    chebyshev_basis,
    least_squares_theta,
)
from stancal.numerics.vector_emulator import VectorEmulator
from stancal.problem.data import CalibrationData
from stancal.problem.fidelity_rho import rho_slopes
from stancal.problem.options import ModelOptions
from stancal.problem.vector_data import VectorCalibrationData
from stancal.stan.registry import (
    STAGE_ONE_BASIS,
    STAGE_ONE_BASIS_FIDELITY,
    STAGE_ONE_FIDELITY,
    STAGE_ONE_GP,
    STAGE_ONE_SCALABLE,
)
from stancal.stan.source import FlatProgram
from stancal.stan.standata import (
    EMULATOR_HYPERPARAMETERS,
    build_emulator_data,
    emulator_run_data,
    fidelity_run_data,
    run_intrinsic_variance,
    theta_low_runs,
    to_stan_json,
)

logger = logging.getLogger("stancal")

EMULATOR_STARTS = 4  # L-BFGS runs from random inits: the runs' likelihood can have more than one mode


def run_stage_one(kind: str | None, data, options, programs: list[FlatProgram], *, backend, seed: int):
    """Stage 1 of the given kind (the registry row's ``stage_one``): a dict
    of the emulator's results for the scalar programs, the basis emulator for
    the vector ones, or None where the program has no stage 1."""
    if kind is None:
        return None
    if kind == STAGE_ONE_GP:
        logger.info("stage 1: fitting the emulator to %d runs", len(data.runs))
        return fit_emulator(data, options, programs[0], backend=backend, seed=seed)
    if kind == STAGE_ONE_SCALABLE:
        return fit_scalable_emulator(data, seed, stochastic=options.stochastic)
    if kind == STAGE_ONE_BASIS:
        return fit_vector_emulator(data, seed)
    if kind == STAGE_ONE_FIDELITY:
        return fit_fidelity_emulator(data, seed)
    if kind == STAGE_ONE_BASIS_FIDELITY:
        return fit_vector_fidelity_emulator(data, seed)
    raise ValueError(f"unknown stage 1 {kind!r}")


def as_chain_starts(emulator: dict[str, Any]) -> dict[str, Any]:
    """Stage 1 of a program that samples the emulator with theta
    (koh_emulator's joint path): its levels only start the chains
    (fitting.inits.fidelity_emulator_inits), so its top level's variance
    factor, a plug-in's, does not enter the fit; the description says so."""
    if "level_rho" not in emulator:
        return emulator
    kept = {k: v for k, v in emulator.items() if k not in ("top_level_variance_factor",
                                                             "top_level_variance_error_ratio")}
    levels = len(emulator["hyperparameters"]["levels"])
    return {**kept, "rho_sampled": True, "stage1": (f"multi-fidelity, the joint path: {levels} "
                               "levels, every level's GP and scale sampled with theta (Kennedy & O'Hagan 2000; "
                               "Goh et al. 2013); the chains start at stage 1's estimates, level by level "
                               "at their posterior mode")}


def fit_emulator(data: CalibrationData, options: ModelOptions, program: FlatProgram, *, backend,
                 seed: int) -> dict[str, Any]:
    """Stage 1 of modular calibration: the emulator's hyperparameters at the
    posterior mode on the unconstrained (log) scale, which for a positive
    parameter with a near log-normal posterior is its median; found by
    optimisation, a fraction of a sampler's cost (and the only affordable route
    for many runs). Also the emulator's leave-one-out accuracy on the runs.
    A stochastic simulator's runs carry their intrinsic variance
    (stancal.fitting.run_variance; stochastic kriging, Ankenman, Nelson &
    Staum 2010): the emulator is then of the simulator's mean."""
    started = time.perf_counter()
    surface, replicates = intrinsic_variance(data, options.stochastic, seed)
    stored = {} if surface is None else {"intrinsic_variance": surface.to_json()}
    stan_data = {**build_emulator_data(data, options), "run_intrinsic_sd": np.sqrt(
        run_intrinsic_variance(data, stored))}
    mode, _ = backend.posterior_mode(program, to_stan_json(stan_data), starts=EMULATOR_STARTS, seed=seed)
    seconds = time.perf_counter() - started
    logger.info("stage 1: emulator hyperparameters by optimisation in %.1f s", seconds)
    loo_error = mode["loo_error"].reshape(-1)  # generated quantities at the mode
    return {
        "hyperparameters": {**{name: mode[name][0, 0].tolist() for name in EMULATOR_HYPERPARAMETERS}, **stored},
        "loo_rmse": float(np.sqrt(np.mean(loo_error**2))),
        "runs_sd": runs_sd(data),
        "replicated_runs": replicates,
        "fit_s": seconds,
    }


def fit_scalable_emulator(data: CalibrationData, seed: int, stochastic: bool = False) -> dict[str, Any]:
    """Stage 1 of modular_hsgp (stancal.numerics.scalable_emulator): hyperparameters,
    weights and theta interpolant; then the theta whose emulator mean fits
    the data best, where the emulator's variance is taken. A stochastic
    simulator's intrinsic variance is on the runs' diagonal (Ankenman,
    Nelson & Staum 2010)."""
    started = time.perf_counter()
    runs = emulator_run_data(data)
    x_points = data.scaling.to_unit(data.physical, data.inputs)
    surface, replicates = intrinsic_variance(data, stochastic, seed)
    stored = {} if surface is None else {"intrinsic_variance": surface.to_json()}
    state, emulator = ScalableEmulator.fit(runs["x_sim"], runs["theta_sim"], runs["y_sim"], x_points, seed,
                                           known=run_intrinsic_variance(data, stored) if stored else None)
    emulator["hyperparameters"].update(stored)
    emulator["replicated_runs"] = replicates
    logger.info("stage 1: emulator hyperparameters at their posterior mode (scipy L-BFGS) on %d of %d "
                "runs; its mean from all runs, interpolated in theta through %d Chebyshev nodes "
                "(error %.1g sd of the output)", emulator["hyperparameter_runs"], len(data.runs),
                emulator["theta_interpolation_points"], emulator["theta_interpolation_error"])
    y = data.scaling.standardise(data.physical[data.output].to_numpy())
    weights = state.mean_weights(x_points)
    theta_unit = least_squares_theta(weights, state.interpolant.degrees, state.hyperparameters.mean, y)
    residual = y - state.hyperparameters.mean - weights @ chebyshev_basis(theta_unit[None, :],
                                                                           state.interpolant.degrees)[0]
    emulator["hyperparameters"]["variance_theta"] = theta_unit.tolist()
    # the error's eigenvalues worth a basis function: noise plus discrepancy bound the noise from above
    emulator["hyperparameters"]["error_threshold"] = ERROR_RANK_SHARE * float(np.mean(residual**2))
    emulator["stage1"] = (f"hyperparameters at their posterior mode by scipy L-BFGS on "
                          f"{emulator['hyperparameter_runs']} of {len(data.runs)} runs; mean from all runs; "
                          f"covariance at theta's least-squares fit: its leading eigenvectors by Nystroem, "
                          f"the rest of each point's variance by local GPs of {NEIGHBOURS} runs")
    emulator["runs_sd"] = runs_sd(data)
    emulator["fit_s"] = time.perf_counter() - started
    logger.info("stage 1 in %.1f s in all", emulator["fit_s"])
    return emulator


def run_columns(data: VectorCalibrationData) -> list[str]:
    """The emulator's inputs: the simulator inputs, then every theta."""
    return [*data.inputs, *(p.name for p in data.all_parameters)]


def fit_vector_emulator(data: VectorCalibrationData, seed: int) -> VectorEmulator:
    """One GP per basis component of the runs' outputs (stancal.numerics.vector_emulator)."""
    xt = data.scaling.to_unit(data.run_settings, run_columns(data))
    started = time.perf_counter()
    # One BLAS thread: the fit is thousands of small (<= 400 x 400) factorisations, which threads barely
    # speed up, and OpenBLAS's threads spin-wait when the cores are busy. On 2 shared cores (load 10-14)
    # Al-5083's 100-run stage 1 took 78 s with 2 threads against 2.7 s with one (docs/al5083.md).
    with threadpool_limits(limits=1, user_api="blas"):
        emulator = VectorEmulator.fit(data.basis, xt, data.run_outputs, seed)
    logger.info("stage 1: %s; one GP per component, hyperparameters at their posterior mode (scipy L-BFGS "
                "on %d of %d runs) in %.1f s", data.basis.describe(), emulator.hyperparameter_runs,
                len(xt), time.perf_counter() - started)
    return emulator


def fit_vector_fidelity_emulator(data: VectorCalibrationData, seed: int) -> VectorEmulator:
    """One multi-fidelity emulator per basis component (Kennedy & O'Hagan
    2000; Le Gratiet & Garnier 2014, level by level): the basis is the
    calibrated simulator's runs', the cheaper runs projected on it
    (VectorEmulator.fit_fidelities); each component's scale and leave-one-out
    error with and without the cheaper runs in the log, and a warning when
    they do not help (VectorEmulator.fidelity_warning)."""
    xt = [data.scaling.to_unit(s, run_columns(data)) for s in [*data.low_fidelity_settings, data.run_settings]]
    weights = [*data.low_fidelity_weights, data.basis.weights(data.run_outputs)]
    started = time.perf_counter()
    with threadpool_limits(limits=1, user_api="blas"):  # many small factorisations: fit_vector_emulator's reason
        emulator = VectorEmulator.fit_fidelities(data.basis, xt, weights, seed)
    logger.info("stage 1: %s; %d levels of fidelity (%s runs, cheapest first), one multi-fidelity GP per "
                "component, hyperparameters level by level in %.1f s", data.basis.describe(), len(xt),
                " + ".join(str(len(x)) for x in xt), time.perf_counter() - started)
    for c, gp in enumerate(emulator.components):
        logger.info("stage 1, component %d: scale on the level below %s; leave-one-out error at the calibrated "
                    "simulator's runs %.3g with the cheaper runs, %.3g without (standardised weights); its own GP's "
                    "variance times %.3g", c + 1, gp.value.rho_text(), gp.value.loo_with, gp.value.loo_without,
                    gp.variance_factor_applied)
    warning = emulator.fidelity_warning()  # the scalar path's warning, at the components that matter
    if warning:
        logger.warning("%s", warning)
    return emulator


def emulator_mean_function(data: CalibrationData, hyperparameters: dict[str, Any], kernel_id: int):
    """The GP emulator's mean given the runs, on the link scale in original
    units (the output's units for a Gaussian output), at fixed
    hyperparameters (stage 1's, or a fit's posterior medians): a function
    of (points with the simulator inputs, theta on the unit box (S, Q)) ->
    (S, points). With the kernels of stancal.numerics.kernels, as the
    programs' emulator; with cheaper simulators' runs, the co-kriging mean."""
    s = data.scaling
    mean = (_fidelity_mean(data, hyperparameters["levels"]) if hyperparameters.get("levels")
            else _one_fidelity_mean(data, hyperparameters, kernel_id))
    theta_low = (hyperparameters.get("levels") or [{}])[-1].get("theta_low_unit")

    def at(points, theta_unit: np.ndarray) -> np.ndarray:
        if theta_low is not None:  # a cheap level's own theta_l (Goh et al. 2013), at stage 1's value
            theta_unit = np.hstack([theta_unit, np.tile(theta_low, (len(theta_unit), 1))])
        x_unit = s.to_unit(points, data.inputs)
        S, P = len(theta_unit), len(x_unit)
        xt = np.hstack([np.repeat(x_unit, S, axis=0), np.tile(theta_unit, (P, 1))])
        return s.original(mean(xt).reshape(P, S).T)

    return at


def runs_sd(data: CalibrationData) -> float:
    """The sd of the calibrated simulator's runs on the link scale, the scale the emulator works on."""
    return float(data.runs_on_link_scale().std(ddof=1))


def _one_fidelity_mean(data: CalibrationData, hyperparameters: dict[str, Any], kernel_id: int):
    """The standardised emulator mean at unit-cube (x, theta) points, given the runs."""
    s = data.scaling
    runs_xt = np.hstack([s.to_unit(data.runs, data.inputs), s.to_unit(data.runs, data.theta_names)])
    sd, mean = float(hyperparameters["emulator_sd"]), float(hyperparameters["emulator_mean"])
    length = np.asarray(hyperparameters["emulator_length_scale"], float)
    k_runs = ard_cross_cov(runs_xt, runs_xt, kernel_id, sd, length)
    intrinsic = run_intrinsic_variance(data, hyperparameters)
    add_run_nugget(k_runs, runs_xt, float(hyperparameters["emulator_nugget"]), intrinsic)
    weights = np.linalg.solve(k_runs, s.standardise(data.runs_on_link_scale()) - mean)
    return lambda xt: mean + ard_cross_cov(xt, runs_xt, kernel_id, sd, length) @ weights


def _fidelity_mean(data: CalibrationData, per_level: list[dict[str, Any]]):
    """The same for the multi-fidelity emulator: the top level's co-kriging
    mean (with a cheap level's own theta_l, of points (x, theta, theta_l))."""
    return mean_function(fidelity_levels(data, per_level))


def fidelity_runs(data: CalibrationData, theta_low_unit: np.ndarray | None = None
                  ) -> list[tuple[np.ndarray, np.ndarray]]:
    """Every simulator's runs, cheapest first, as the emulator sees them:
    (x, theta) on the unit cube, y standardised; with a cheap level's own
    theta_l, (x, theta, theta_l), the expensive runs' theta_l at
    ``theta_low_unit`` (stancal.numerics.multifidelity_theta)."""
    runs = theta_low_runs(data, theta_low_unit) if data.theta_low_names else fidelity_run_data(data)
    return [(np.hstack([r["x_sim"], r["theta_sim"]]), r["y_sim"]) for r in runs]


def fidelity_levels(data: CalibrationData, per_level: list[dict[str, Any]]) -> list[Level]:
    """The multi-fidelity emulator that stage 1's per-level hyperparameters
    describe, on the data's runs (a cheap level's own theta_l at stage 1's estimate)."""
    theta_low = per_level[-1].get("theta_low_unit")
    return [Level(Hyperparameters.from_stan(h), float(h["rho"]), xt, y, np.asarray(h.get("rho_slope", []), float))
            for h, (xt, y) in zip(per_level, fidelity_runs(data, theta_low), strict=True)]


def rho_of_inputs(data: CalibrationData, levels: list[Level]) -> dict[str, Any]:
    """A linear rho's coefficients (on the unit cube: rho at the inputs' low
    corner, then each input's slope over its range), its least and largest
    value over the inputs' box, and its profile along each input (the others
    at their centre), the input in its own units; empty for a constant rho."""
    if not any(len(lv.rho_slope) for lv in levels[1:]):
        return {}
    low, width = data.scaling.low, data.scaling.width
    grid = {name: (low[name] + width[name] * RHO_PROFILE_GRID).tolist() for name in data.inputs}
    return {"level_rho_slope": [dict(zip(data.inputs, lv.rho_slope.tolist(), strict=True)) for lv in levels[1:]],
            "level_rho_range": [list(rho_range(lv)) for lv in levels[1:]],
            "level_rho_profile": [{"inputs": grid, "rho": dict(zip(data.inputs, rho_profile(lv).tolist(), strict=True))}
                                  for lv in levels[1:]]}


def fit_fidelity_emulator(data: CalibrationData, seed: int) -> dict[str, Any]:
    """Stage 1 with runs of cheaper simulators (stancal.numerics.multifidelity):
    each level's GP and scale at their posterior mode, level by level (Le
    Gratiet & Garnier 2014); the top level's leave-one-out error with and
    without the cheaper runs, and a warning when they do not help. The top
    level's GP, from few runs, has its variance scaled by its plug-in
    predictor's mean squared error under its hyperparameters' posterior
    over its own variance (stancal.numerics.multifidelity_variance)."""
    if data.theta_low_names:  # a cheap level's own theta_l: fitted with it (timed there)
        return fit_theta_low_emulator(data, seed)
    started = time.perf_counter()
    runs = fidelity_runs(data)
    slopes = rho_slopes(data.low_fidelity_rho, len(data.inputs))  # rho linear in the inputs, or constant
    correction = variance_correction(fit_levels([xt for xt, _ in runs], [y for _, y in runs], seed, slopes), seed)
    levels = correction.levels
    value = cheap_runs_value(levels, seed)
    seconds = time.perf_counter() - started
    logger.info("stage 1: %d levels of fidelity (%s runs, cheapest first), hyperparameters level by level "
                "in %.1f s; scale on the level below %s; leave-one-out error at the calibrated simulator's runs "
                "%.3g with the cheaper runs, %.3g without (standardised units)", len(levels),
                " + ".join(str(len(y)) for _, y in runs), seconds, value.rho_text(),
                value.loo_with, value.loo_without)
    logger.info("stage 1: the calibrated simulator's own GP has its variance times %.3g: its plug-in's mean squared "
                "error under its hyperparameters' posterior is %.3g (Monte Carlo sd %.2g) times its variance, "
                "from %d runs%s", correction.applied, correction.factor, correction.factor_sd, len(runs[-1][1]),
                " that pin them loosely" if correction.factor > 1 else "")
    if value.warning():
        logger.warning("%s", value.warning())
    per_level = [{**lv.hyperparameters.as_stan(), "rho": lv.rho, "rho_slope": lv.rho_slope.tolist()}
                 for lv in levels]  # the cheapest's rho: 1, unused
    return {
        # every level's GP; no single-level names, which would read as the top level's emulator
        "hyperparameters": {"levels": per_level},
        "loo_rmse": value.loo_with,
        "loo_rmse_without_low_fidelity": value.loo_without,
        "level_rho": value.rho,
        **rho_of_inputs(data, levels),
        "top_level_variance_factor": correction.applied,
        "top_level_variance_error_ratio": [correction.factor, correction.factor_sd],  # measured, its MC sd
        "warning": value.warning(),
        "runs_sd": runs_sd(data),
        "stage1": (f"multi-fidelity: {len(levels)} levels, hyperparameters level by level at their posterior "
                   f"mode (scipy L-BFGS), the top level's variance scaled for their uncertainty, "
                   f"co-kriging given every level's runs"),
        "fit_s": seconds,
    }
