"""calibrate(): from a CalibrationData to a CalibrationResult."""

from __future__ import annotations

import logging
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from stancal.results import diagnostics as sampler_checks
from stancal.results import modes as mode_checks
from stancal.stan.backends import get_backend
from stancal.problem.data import CalibrationData
from stancal.problem.functional import check_functional, parametrization_advice
from stancal.numerics.hsgp import BasisTooLargeError, HSGPBasis, basis_problems, first_basis, refined_basis
from stancal.fitting.inits import spread_theta_inits
from stancal.fitting.l2 import l2_result
from stancal.stan.registry import (
    EXACT_SIZE_LIMIT,
    HSGP_METHODS,
    LATENT_PROGRAM,
    RESTRICTED_DISCREPANCIES,
    SCALABLE_PROGRAM,
    Method,
    ModelOptions,
    model_spec,
)
from stancal.numerics.quadrature import input_box_quadrature
from stancal.results.result import CalibrationResult, build_datatree
from stancal.fitting.seeds import command_seed
from stancal.stan.source import FlatProgram, flatten
from stancal.numerics.scalable_emulator import (ERROR_RANK_SHARE, MAX_ERROR_RANK, NEIGHBOURS, ScalableEmulator, chebyshev_basis,
                                least_squares_theta)
from stancal.stan.standata import (
    EMULATOR_HYPERPARAMETERS,
    build_emulator_data,
    build_stan_data,
    default_new_points,
    emulator_run_data,
    scalable_emulator_of,
    to_stan_json,
)

logger = logging.getLogger("stancal")

L2 = "l2"  # not a Stan program: the projection of another method's zeta draws
_DIAGNOSED = ["theta", "noise_sd", "delta_sd", "delta_length_scale", "delta_relevance", "rho", "beta", "phi",
              "theta_function_sd", *EMULATOR_HYPERPARAMETERS]


def _latent_reason(data: CalibrationData, options: ModelOptions) -> str | None:
    """Why the latent-GP programs are needed (the outputs, or functional theta), or None."""
    return data.latent_reason or ("functional theta" if options.functional else None)


def require_gaussian(what: str, data: CalibrationData, options: ModelOptions | None = None) -> None:
    """The one guard of what works on the Gaussian programs only (their GP is
    integrated out): raise a ValueError that names ``what`` and the reason."""
    reason = _latent_reason(data, options or ModelOptions())
    if reason:
        raise ValueError(f"{what} needs Gaussian, uncensored outputs and scalar theta; this problem "
                         f"has {reason}. Calibrate it with stancal calibrate")


def choose_method(data: CalibrationData, simulator: str | Path | None, method: str | None,
                  options: ModelOptions | None = None) -> Method:
    """The program to run: the user's method, or koh with a simulator and
    koh_emulator from runs; their latent-GP versions when the outputs or
    theta need them."""
    options = options or ModelOptions()
    reason = _latent_reason(data, options)
    base = _base_method(data, simulator, method)
    if reason is not None:  # every method has a latent version
        unsupported = [name for name, used in (
            (f"discrepancy '{options.discrepancy}'", options.discrepancy in RESTRICTED_DISCREPANCIES),
            ("estimate_rho", options.estimate_rho),
            ("approximation 'hsgp'", options.approximation == "hsgp")) if used]
        if unsupported:
            raise ValueError(f"{reason} runs on the latent-GP programs, which do not support "
                             f"{', '.join(unsupported)}")
        return LATENT_PROGRAM[base]
    return SCALABLE_PROGRAM[base] if _scalable(data, base, options) else base


def dense_size(data: CalibrationData, method: Method) -> int:
    """The size of the dense matrix the exact program factorises at every
    gradient: the points, plus the runs for an emulator."""
    runs = len(data.runs) if data.runs is not None and model_spec(method).needs_runs else 0
    return len(data.physical) + runs


def _scalable(data: CalibrationData, base: Method, options: ModelOptions) -> bool:
    """Whether the scalable (hsgp) program runs: asked for, or auto above
    EXACT_SIZE_LIMIT, said in one line. What it cannot do is an error, under
    auto too when the problem is above the limit: never a silent dense
    matrix of thousands of rows."""
    if base in HSGP_METHODS:
        return True
    if options.approximation == "exact" or base not in SCALABLE_PROGRAM:
        return False
    size = dense_size(data, base)
    obstacles = [why for why, present in (
        (f"discrepancy '{options.discrepancy}' (needs the dense GP)", options.discrepancy in RESTRICTED_DISCREPANCIES),
        ("covariates in the discrepancy (a Hilbert-space basis vanishes at its boundary, so it cannot "
         "switch a covariate off)", options.has_discrepancy and len(data.discrepancy_inputs) > len(data.inputs)),
    ) if present]
    if options.approximation == "hsgp":
        if obstacles:
            raise ValueError(f"approximation 'hsgp' does not support {'; '.join(obstacles)}. Use "
                             f"approximation = 'exact', or leave them out")
        return True
    if size <= EXACT_SIZE_LIMIT:
        return False
    if obstacles:
        raise ValueError(f"{len(data.physical)} points" + (f" and {size - len(data.physical)} runs" if
                         size > len(data.physical) else "") + f" exceed the exact programs' limit of "
                         f"{EXACT_SIZE_LIMIT}, but the scalable programs do not support {'; '.join(obstacles)}. "
                         f"Leave them out, or set approximation = 'exact' to run the dense GP anyway (slow)")
    logger.info("%d points%s: above %d, so %s runs (Hilbert-space discrepancy%s); approximation = 'exact' "
                "keeps the dense GP", len(data.physical), f" + {size - len(data.physical)} runs" if
                size > len(data.physical) else "", EXACT_SIZE_LIMIT, SCALABLE_PROGRAM[base],
                ", precomputed-weight emulator" if model_spec(base).needs_runs else "")
    return True


def _base_method(data: CalibrationData, simulator: str | Path | None, method: str | None) -> Method:
    if method is None:
        if simulator is None and not data.has_runs:
            raise ValueError("give a Stan simulator, simulator runs, or both")
        return Method.KOH if simulator is not None else Method.KOH_EMULATOR
    chosen = Method(method)
    if model_spec(chosen).needs_simulator and simulator is None:
        raise ValueError(f"method '{chosen}' needs a Stan simulator file")
    if model_spec(chosen).needs_runs and not data.has_runs:
        raise ValueError(f"method '{chosen}' needs simulator runs")
    return chosen


def stan_programs(chosen: Method, simulator: str | Path | None = None,
                  program: str | Path | None = None) -> list[FlatProgram]:
    """The flat programs a calibration with ``chosen`` runs: the method's (or
    the user's copy), after stage 1's emulator where it has one."""
    aliases = {"simulator.stan": Path(simulator)} if simulator is not None else {}
    main = flatten(Path(program) if program else model_spec(chosen).path, aliases=aliases)
    if chosen in (Method.MODULAR, Method.KOH_LATENT_EMULATOR):  # both fix stage 1's hyperparameters
        return [flatten(model_spec("emulator").path), main]
    return [main]


# a discrepancy below this fraction of the noise sd is not checked against its basis
NEGLIGIBLE_DISCREPANCY = 0.1
VARIANCE_TOLERANCE = 0.05  # relative change of the observations' predictive sd worth telling
EMULATOR_STARTS = 4  # L-BFGS runs from random inits: the runs' likelihood can have more than one mode


def fit_emulator(data: CalibrationData, options: ModelOptions, program: FlatProgram, *, backend,
                 seed: int) -> dict[str, Any]:
    """Stage 1 of modular calibration: the emulator's hyperparameters at the
    posterior mode on the unconstrained (log) scale, which for a positive
    parameter with a near log-normal posterior is its median; found by
    optimisation, a fraction of a sampler's cost (and the only affordable route
    for many runs). Also the emulator's leave-one-out accuracy on the runs."""
    started = time.perf_counter()
    mode, _ = backend.posterior_mode(program, to_stan_json(build_emulator_data(data, options)),
                                     starts=EMULATOR_STARTS, seed=seed)
    seconds = time.perf_counter() - started
    logger.info("stage 1: emulator hyperparameters by optimisation in %.1f s", seconds)
    loo_error = mode["loo_error"].reshape(-1)  # generated quantities at the mode
    return {
        "hyperparameters": {name: mode[name][0, 0].tolist() for name in EMULATOR_HYPERPARAMETERS},
        "loo_rmse": float(np.sqrt(np.mean(loo_error**2))),
        "runs_sd": float(data.runs_on_link_scale().std(ddof=1)),  # the scale the emulator works on
        "fit_s": seconds,
    }


def fit_scalable_emulator(data: CalibrationData, seed: int) -> dict[str, Any]:
    """Stage 1 of modular_hsgp (stancal.numerics.scalable_emulator): hyperparameters,
    weights and theta interpolant; then the theta whose emulator mean fits
    the data best, where the emulator's variance is taken."""
    started = time.perf_counter()
    runs = emulator_run_data(data)
    x_points = data.scaling.to_unit(data.physical, data.inputs)
    state, emulator = ScalableEmulator.fit(runs["x_sim"], runs["theta_sim"], runs["y_sim"], x_points, seed)
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
    emulator["runs_sd"] = float(data.runs_on_link_scale().std(ddof=1))
    emulator["fit_s"] = time.perf_counter() - started
    logger.info("stage 1 in %.1f s in all", emulator["fit_s"])
    return emulator


def _check_emulator_variance(tree, data: CalibrationData, emulator: dict[str, Any],
                             stan_json: dict[str, Any]) -> list[str]:
    """The emulator's covariance entered the fit at one theta (its basis
    columns, plus the rest as one variance averaged over the points): how
    far each observation's predictive sd is from the one the fit gave it, at
    posterior draws of theta; told when it matters."""
    theta_unit = (np.asarray(tree["posterior"]["theta"]).reshape(-1, len(data.parameters))
                  - data.theta_lower) / (data.theta_upper - data.theta_lower)
    state = scalable_emulator_of(data, emulator["hyperparameters"])
    x = data.scaling.to_unit(data.physical, data.inputs)
    noise_var = (float(np.median(np.asarray(tree["posterior"]["noise_sd"]))) / data.scaling.y_scale) ** 2
    columns = np.asarray(stan_json["emulator_error_basis"]).reshape(len(x), -1)
    plug_in = noise_var + (columns**2).sum(1) + float(stan_json["emulator_variance"])
    rng = np.random.default_rng(0)
    variances = [state.variance(x, theta) for theta in theta_unit[rng.choice(len(theta_unit), 8, replace=False)]]
    # the sd each observation should have had, against the one the fit gave it
    moved = max(float(np.max(np.abs(np.sqrt((noise_var + v) / plug_in) - 1))) for v in variances)
    emulator["variance_check"] = {
        "max_relative_change_of_sd": moved,
        "max_emulator_sd_over_noise_sd": float(np.sqrt(max(v.max() for v in variances) / noise_var)),
        "error_basis_rank": columns.shape[1]}
    messages = [] if columns.shape[1] < MAX_ERROR_RANK else [
        f"the emulator's error at the points entered the fit through its {MAX_ERROR_RANK} leading "
        f"eigenvectors, the most stancal takes; the rest was treated as independent between points, "
        f"which narrows theta's band if it is large: more runs would shrink it"]
    if moved <= VARIANCE_TOLERANCE:
        return messages
    return messages + [
        f"the emulator's covariance entered the fit at theta's least-squares fit; at posterior draws of theta "
        f"an observation's predictive sd differs from the one used by up to {moved:.0%}: theta's band may be "
        f"off by about as much. More runs where the posterior lies, or approximation = 'exact' on a "
        f"subsample, would settle it"]


def _with_basis(options: ModelOptions, basis: HSGPBasis) -> ModelOptions:
    return replace(options, basis_functions=basis.counts, boundary_factor=basis.boundary_factors)


def _check_basis(tree, data: CalibrationData, options: ModelOptions,
                 chosen_by_user: bool) -> tuple[ModelOptions, bool, list[str]]:
    """Riutort-Mayol et al.'s check of the basis against the fitted length
    scales; a basis stancal chose is rebuilt from them once (refit = True)."""
    posterior = tree["posterior"]
    if np.median(posterior["delta_sd"]) < NEGLIGIBLE_DISCREPANCY * np.median(posterior["noise_sd"]):
        return options, False, []  # no shape worth representing: its length scales are the prior's
    widths = np.array([data.scaling.width[c] for c in data.discrepancy_inputs])
    fitted = np.asarray(posterior["delta_length_scale"]).reshape(-1, len(widths)) / widths
    basis = HSGPBasis(options.basis_functions, options.boundary_factor)
    problems = basis_problems(basis, options.kernel, fitted, data.discrepancy_inputs)
    if not problems:
        return options, False, []
    advice = "set basis_functions and boundary_factor per input to change it"
    if not chosen_by_user:
        try:
            better = refined_basis(options.kernel, basis, fitted, data.discrepancy_inputs)
        except BasisTooLargeError as err:
            advice = str(err)
        else:
            logger.info("Hilbert-space basis: %s; refitting with %s", "; ".join(problems), better.describe())
            return _with_basis(options, better), True, []
    return options, False, [f"the Hilbert-space discrepancy's basis ({basis.describe()}) may be inadequate: "
                            f"{'; '.join(problems)}. {advice}"]


def _sample(stan_backend, flat: FlatProgram, data: CalibrationData, chosen: Method, options: ModelOptions,
            fit_points: pd.DataFrame, emulator: dict[str, Any], prior: bool, sampler: dict[str, Any]):
    """One fit of the program: (sample, its Stan data, DataTree, parameter names)."""
    stan_data = build_stan_data(data, chosen, options, fit_points,
                                emulator_hyperparameters=emulator.get("hyperparameters"))
    inits = spread_theta_inits(sampler["chains"], len(data.parameters), np.random.default_rng(sampler["seed"]))
    logger.info("sampling %s: %d chains x (%d warmup + %d draws) with %s",
                chosen, sampler["chains"], sampler["warmup"], sampler["draws"], stan_backend.name)
    stan_json = to_stan_json(stan_data)
    sample = stan_backend.sample(flat, stan_json, inits=inits, **sampler)
    parameter_names = stan_backend.parameter_names(flat)  # the program's own, edited or not
    tree = build_datatree(sample, data, fit_points, parameter_names, options)
    if prior:
        prior_sample = stan_backend.sample(flat, {**stan_json, "prior_only": 1}, inits=inits,
                                           **{**sampler, "seed": sampler["seed"] + 1})
        prior_tree = build_datatree(prior_sample, data, fit_points, parameter_names, options)
        tree["prior"] = prior_tree["posterior"]
        tree["prior_predictive"] = prior_tree["posterior_predictive"]
        tree["prior_stan_parameters"] = prior_tree["stan_parameters"]  # the program's own, for SBC
    return sample, stan_json, tree, parameter_names


def calibrate(
    data: CalibrationData,
    *,
    simulator: str | Path | None = None,
    method: str | None = None,
    program: str | Path | None = None,
    discrepancy: str | None = None,
    kernel: str = "se",
    estimate_rho: bool = False,
    mean_formula: str | None = None,
    mean_intercept: bool = False,
    scaled_lambda: float | None = None,
    functional: tuple[str, ...] | list[str] = (),
    functional_inputs: tuple[str, ...] | list[str] = (),
    functional_parametrization: str = "centred",
    approximation: str = "auto",
    basis_functions: tuple[int, ...] | list[int] = (),
    boundary_factor: tuple[float, ...] | list[float] = (),
    new_points: pd.DataFrame | None = None,
    chains: int = 4,
    warmup: int = 1000,
    draws: int = 1000,
    seed: int | None = None,
    backend: str | None = None,
    adapt_delta: float = 0.9,
    max_treedepth: int = 10,
    out_dir: str | Path | None = None,
    prior: bool = False,
) -> CalibrationResult:
    """Calibrate theta (Kennedy & O'Hagan 2001) and return the posterior.

    ``simulator``: a Stan file defining ``vector simulator(matrix X, vector theta)``.
    ``method``: koh (cheap simulator), koh_emulator (joint, from runs),
    modular (two-stage, from runs) or l2 (L2 calibration, Tuo & Wu 2015: each
    posterior draw of the real process zeta, from koh with a simulator or
    koh_emulator from runs, projected onto the simulator over the input box);
    by default koh with a simulator, else koh_emulator.
    ``program``: your own copy of the method's .stan file.
    ``discrepancy``: gp (KOH), orthogonal (orthogonal to df/dtheta: theta
    targets the L2 projection; Plumlee 2017), scaled (S-GaSP, Gu & Wang 2018,
    penalty ``scaled_lambda``, default sqrt(N)) or none. orthogonal and scaled
    need method koh. Default: gp, or none with functional theta.
    ``functional``, ``functional_inputs``: theta that vary over inputs,
    theta_j(x) = lo + (hi - lo) logistic(GP_j(x)) (review section 8.2);
    ``functional_parametrization`` of that GP: centred (data that pin theta(x)
    closely) or non_centred (noisy or sparse data); a fit whose sampler
    struggles is told to try the other.
    Non-Gaussian (``CalibrationData(likelihood=...)``) or censored outputs and
    functional theta run on the latent-GP programs koh_latent (simulator) and
    koh_latent_emulator (runs).
    ``mean_formula``: terms h(x, z) of a discrepancy mean h' beta, a formula
    over the physical data's columns such as ``"I(v**2) + C(batch)"``;
    ``mean_intercept`` adds a constant term ``Intercept``.
    ``approximation``: exact (dense GPs), hsgp (for thousands of points and
    runs: a Hilbert-space discrepancy, Riutort-Mayol et al. 2023, and with
    runs a modular emulator of precomputed weights; programs koh_hsgp and
    modular_hsgp) or auto (hsgp above models.EXACT_SIZE_LIMIT points plus
    runs). ``basis_functions`` and ``boundary_factor``: the Hilbert-space
    basis per discrepancy input (default: chosen from the length scales,
    checked after the fit and refitted once if it cannot represent them).
    ``out_dir``: the posterior is written there as soon as sampling ends.
    ``prior``: also draw from the prior (same program, ``prior_only = 1``) into
    the ``prior`` and ``prior_predictive`` groups.
    """
    if discrepancy is None:  # functional theta are flexible enough without one (review section 8.2)
        discrepancy = "none" if functional else "gp"
    options = ModelOptions(discrepancy, kernel, estimate_rho, mean_formula, mean_intercept, scaled_lambda,
                           tuple(functional), tuple(functional_inputs), functional_parametrization,
                           approximation, tuple(basis_functions), tuple(boundary_factor))
    check_functional(data, options.functional, options.functional_inputs)
    l2 = method == L2
    if l2:
        require_gaussian("method 'l2'", data, options)
    chosen = choose_method(data, simulator, None if l2 else method, options)
    programs = stan_programs(chosen, simulator, program)
    *stage_one, flat = programs
    stan_backend = get_backend(backend)
    stan_backend.compile(programs)
    seed = command_seed(seed)
    new_points = default_new_points(data) if new_points is None else new_points.reset_index(drop=True)
    quadrature = None
    if l2:  # zeta is drawn at the quadrature nodes too, with the sampler's own RNG
        quadrature = input_box_quadrature(data)
        new_points = new_points[data.inputs]
        fit_points = pd.concat([new_points, quadrature.nodes], ignore_index=True)
    else:
        fit_points = new_points

    emulator: dict[str, Any] = {}
    if stage_one:
        logger.info("stage 1: fitting the emulator to %d runs", len(data.runs))
        emulator = fit_emulator(data, options, stage_one[0], backend=stan_backend, seed=seed)
    sampler = dict(chains=chains, warmup=warmup, draws=draws, seed=seed, adapt_delta=adapt_delta,
                   max_treedepth=max_treedepth)
    if chosen is Method.MODULAR_HSGP:
        emulator = fit_scalable_emulator(data, seed)
    approximation_messages: list[str] = []
    if chosen in HSGP_METHODS:
        options = replace(options, approximation="hsgp")
        if not options.basis_functions:
            options = _with_basis(options, first_basis(options.kernel, data.discrepancy_inputs))
    sample, stan_json, tree, parameter_names = _sample(
        stan_backend, flat, data, chosen, options, fit_points, emulator, prior, sampler)
    if chosen in HSGP_METHODS and options.has_discrepancy:
        options, refit, approximation_messages = _check_basis(tree, data, options,
                                                              chosen_by_user=bool(basis_functions))
        if refit:
            sample, stan_json, tree, parameter_names = _sample(
                stan_backend, flat, data, chosen, options, fit_points, emulator, prior, sampler)
            _, _, approximation_messages = _check_basis(tree, data, options, chosen_by_user=True)
    if chosen is Method.MODULAR_HSGP:
        approximation_messages += _check_emulator_variance(tree, data, emulator, stan_json)
    timing = {"compile_s": sample.compile_seconds,
              "sample_s": sample.sample_seconds + emulator.get("fit_s", 0.0)}
    posterior = tree["posterior"].to_dataset()
    result = CalibrationResult(
        idata=tree, data=data, method=str(chosen), backend=stan_backend.name, options=options,
        program=flat, timing=timing, emulator=emulator,
    )
    if out_dir is not None:  # nothing below may lose the draws
        result.save(Path(out_dir) / "posterior.nc")
    if quadrature is not None:
        logger.info("L2 calibration: projecting %d draws of zeta onto the simulator",
                    tree["posterior"].sizes["chain"] * tree["posterior"].sizes["draw"])
        result = l2_result(result, quadrature, len(new_points))
        tree, posterior = result.idata, result.idata["posterior"].to_dataset()
    result.modes, weights_unavailable = mode_checks.modes_of(
        tree, data.theta_names, data.theta_upper - data.theta_lower,
        # L2's theta is a projection, not a density's
        None if quadrature is not None else lambda: stan_backend.log_density_functions(flat, stan_json), seed)
    result.diagnostics = sampler_checks.check_sampler(
        posterior, tree["sample_stats"].to_dataset(), max_treedepth,
        [v for v in posterior if v in _DIAGNOSED or v in parameter_names], [m.chains for m in result.modes])
    result.diagnostics.messages.extend(parametrization_advice(options, result.diagnostics))
    result.diagnostics.messages.extend(approximation_messages)
    sampler_checks.report(result.diagnostics)
    mode_checks.report(result.modes, weights_unavailable)
    if out_dir is not None:
        result.save(Path(out_dir) / "posterior.nc")
    return result
