"""calibrate(): from a CalibrationData to a CalibrationResult, as
plan -> stage 1 -> sample -> post-fit checks (Kennedy & O'Hagan 2001)."""

from __future__ import annotations

import logging
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from stancal.fitting.approximation_checks import check_basis, check_emulator_variance
from stancal.fitting.confounding import resolve_confounding
from stancal.fitting.inits import fidelity_emulator_inits, spread_theta_inits
from stancal.fitting.l2 import l2_result
from stancal.fitting.parametrization_fallback import with_fallback
from stancal.fitting.plan import Plan, model_options, plan_scalar
from stancal.fitting.postfit import check_fit, save_draws
from stancal.fitting.run_variance import with_replicated_runs
from stancal.fitting.seeds import command_seed
from stancal.fitting.simulator_check import check_simulator_at_start, explained
from stancal.fitting.stage_one import as_chain_starts, run_stage_one
from stancal.numerics.quadrature import Quadrature, input_box_quadrature
from stancal.problem.data import CalibrationData
from stancal.problem.options import ModelOptions
from stancal.problem.sampling import SamplerOptions
from stancal.results.diagnostics import parametrization_advice
from stancal.results.result import CalibrationResult, add_prior, build_datatree
from stancal.stan.backends import StanRuntimeError, WarmStart, get_backend
from stancal.stan.registry import STAGE_ONE_SCALABLE
from stancal.stan.source import FlatProgram
from stancal.stan.standata import EMULATOR_HYPERPARAMETERS, build_stan_data, default_new_points, to_stan_json

logger = logging.getLogger("stancal")

_DIAGNOSED = ["theta", "noise_sd", "nu", "noise_gp_sd", "noise_length_scale", "delta_sd", "delta_length_scale",
              "delta_relevance", "rho", "beta", "phi", "theta_function_sd", *EMULATOR_HYPERPARAMETERS]


def _plan_alone(options: ModelOptions, **files) -> None:
    """A plan replaces the simulator, method, program and model keywords: giving both is an error."""
    defaults = model_options()
    clashing = sorted([k for k, v in files.items() if v is not None]
                      + [f.name for f in fields(options) if getattr(options, f.name) != getattr(defaults, f.name)])
    if clashing:
        raise ValueError(f"give either a plan or {', '.join(clashing)}: the plan already holds them")


@dataclass
class _Fit:
    """One sampling of the plan's program: its Stan data and DataTree."""

    sample: Any
    stan_json: dict[str, Any]
    tree: Any
    parameter_names: list[str]


def _sample(stan_backend, flat: FlatProgram, data: CalibrationData, plan: Plan, options: ModelOptions,
            fit_points: pd.DataFrame, emulator: dict[str, Any], prior: bool, sampler: dict[str, Any],
            warm_start: WarmStart | None = None) -> _Fit:
    """One fit of the program, with the prior's draws too when asked;
    ``warm_start``: from an earlier fit's draws and adaptation."""
    stan_json = to_stan_json(build_stan_data(data, plan.program.data, options, fit_points,
                                             emulator_hyperparameters=emulator.get("hyperparameters")))
    if warm_start is not None and warm_start.related:  # from another program: what this one has in that shape
        warm_start = warm_start.fitted(stan_backend.parameter_shapes(flat, stan_json))
    # a sampled multi-fidelity emulator starts at stage 1's estimates (none with one fidelity: no stage 1)
    emulator_start = fidelity_emulator_inits(emulator.get("hyperparameters")) if plan.program.samples_emulator \
        else {}
    inits = warm_start.inits if warm_start is not None else [
        {**start, **emulator_start} for start in spread_theta_inits(
            sampler["chains"], len(data.parameters), np.random.default_rng(sampler["seed"]))]
    simulator, points = plan.simulator if plan.program.simulator else None, data.physical[data.inputs]
    check_simulator_at_start(stan_backend, flat, stan_json, inits, simulator, points)
    logger.info("sampling %s: %d chains x (%d warmup + %d draws) with %s",
                plan.name, sampler["chains"], sampler["warmup"], sampler["draws"], stan_backend.name)
    try:
        sample = stan_backend.sample(flat, stan_json, inits=inits, warm_start=warm_start, **sampler)
    except StanRuntimeError as err:
        raise explained(err, simulator, points) from None
    parameter_names = stan_backend.parameter_names(flat)  # the program's own, edited or not
    tree = build_datatree(sample, data, fit_points, parameter_names, options)
    if prior:
        prior_sample = stan_backend.sample(flat, {**stan_json, "prior_only": 1}, inits=inits,
                                           **{**sampler, "seed": sampler["seed"] + 1})
        prior_tree = build_datatree(prior_sample, data, fit_points, parameter_names, options)
        add_prior(tree, prior_tree)
    return _Fit(sample, stan_json, tree, parameter_names)


def _sample_checked(sample_once, data: CalibrationData, plan: Plan, emulator: dict[str, Any],
                    chosen_by_user: bool, max_treedepth: int) -> tuple[_Fit, ModelOptions, list[str]]:
    """Sample, then check the approximation the program makes, if it makes
    one: a Hilbert-space basis stancal chose is rebuilt once from the fitted
    length scales; the scalable emulator's covariance is checked at the draws.
    A latent discrepancy the plan parametrised whose fit saturates the tree
    depth is refitted once the other way (parametrization_fallback)."""
    options = plan.options
    fit = sample_once(options)
    if plan.program.latent and options.has_discrepancy and not plan.parametrization_given:
        fit, options = with_fallback(sample_once, fit, options, max_treedepth, lambda f: f.tree)
    messages: list[str] = []
    if plan.program.approximation == "hsgp" and options.has_discrepancy:
        options, refit, messages = check_basis(fit.tree, data, options, chosen_by_user=chosen_by_user)
        if refit:
            fit = sample_once(options)
            _, _, messages = check_basis(fit.tree, data, options, chosen_by_user=True)
    if plan.stage_one == STAGE_ONE_SCALABLE:  # its covariance entered at one theta
        messages += check_emulator_variance(fit.tree, data, emulator, fit.stan_json)
    return fit, options, messages


def _prediction_points(data: CalibrationData, new_points: pd.DataFrame | None,
                       l2: bool) -> tuple[pd.DataFrame, pd.DataFrame, Quadrature | None]:
    """Where f, delta and zeta are drawn: the user's points (or a default
    grid), plus the quadrature nodes over the input box for L2."""
    new_points = default_new_points(data) if new_points is None else new_points.reset_index(drop=True)
    if not l2:
        return new_points, new_points, None
    quadrature = input_box_quadrature(data)  # zeta is drawn at its nodes too, with the sampler's own RNG
    new_points = new_points[data.inputs]
    return new_points, pd.concat([new_points, quadrature.nodes], ignore_index=True), quadrature


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
    mean_centred: bool = False,
    scaled_lambda: float | None = None,
    functional: tuple[str, ...] | list[str] = (),
    functional_inputs: tuple[str, ...] | list[str] = (),
    functional_parametrization: str = "centred",
    approximation: str = "auto",
    basis_functions: tuple[int, ...] | list[int] = (),
    boundary_factor: tuple[float, ...] | list[float] = (),
    discrepancy_parametrization: str = "auto",
    noise: str = "iid",
    noise_inputs: tuple[str, ...] | list[str] = (),
    stochastic: bool = False,
    biased_sources: tuple[str, ...] | list[str] = (),
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
    plan: Plan | None = None,
    warm_start: WarmStart | None = None,
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
    ``discrepancy_parametrization`` of the latent programs' discrepancy GP:
    centred, non_centred, partial (partially non-centred with the data's
    information, koh_latent only; Christensen, Roberts & Sköld 2006) or auto
    (centred when the data's information per point dominates the prior's
    precision at most points, Papaspiliopoulos, Roberts & Sköld 2007, or
    partial where the program offers it: stancal.numerics.parametrization);
    under auto, a fit with more than 5 % of its transitions at the maximum
    tree depth is refitted once the other way (non-centred after partial) and
    the better kept. The summary says which
    ran and why (options.discrepancy_parametrization_reason).
    ``noise``: the measurement noise (docs/noise.md): iid (one sd), per_source
    (one sd per the data's ``source``), student_t (robust, its degrees of
    freedom estimated; Lange, Little & Taylor 1989) or heteroscedastic (the
    log sd a GP over ``noise_inputs``, by default every simulator input;
    Binois, Gramacy & Ludkovski 2018; Sung, Barber & Walker 2022), on koh,
    koh_emulator and modular; the data's known ``noise_sd`` adds in quadrature to each.
    Non-Gaussian (``CalibrationData(likelihood=...)``) or censored outputs and
    functional theta run on the latent-GP programs koh_latent (simulator) and
    koh_latent_emulator (runs).
    ``stochastic``: the simulator's runs scatter at equal inputs and theta
    (agent-based, Monte Carlo): its own variance, smoothed over the inputs
    from the replicated runs, sits on the emulator runs' diagonal and not at
    the physical points (stochastic kriging, Ankenman, Nelson & Staum 2010;
    docs/noise.md); on modular and modular_hsgp, the default with it.
    ``biased_sources``: sources of the data's ``source`` column whose readings
    carry a bias of their own over the simulator inputs, a GP beside the
    shared discrepancy (Gu et al. 2023's multi-source calibration; review
    section 8.1.3; docs/noise.md); the other sources are references and anchor
    the discrepancy's level. On koh, koh_emulator and modular, with or without a discrepancy.
    ``mean_formula``: terms h(x, z) of a discrepancy mean h' beta, a formula
    over the physical data's columns such as ``"I(v**2) + C(batch)"``;
    ``mean_intercept`` adds a constant term ``Intercept``; it is dropped when a
    theta's effect on the link scale is a constant (a scale under a log link),
    found before sampling (stancal.fitting.confounding), and the terms are
    then ``mean_centred``: centred over the points as beside a constant.
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
    ``plan``: a plan made earlier (stancal.fitting.plan), which then replaces
    ``simulator``, ``method``, ``program`` and the model's options (and
    stage 1, where the plan holds its result: Plan.stage_one_result).
    ``warm_start``: start the chains from an earlier fit of nearly the same
    model and data (stancal.fitting.warm_start; the gap diagnosis's refits,
    and its candidates, whose parameters the baseline lacks or shapes
    otherwise are left to Stan's inits: WarmStart.fitted), with a
    ``warmup`` as short as that allows.
    """
    # the sampler's options first: a bad one is said before anything is planned or compiled
    sampling = SamplerOptions(chains, warmup, draws, seed, adapt_delta, max_treedepth)
    options = model_options(discrepancy, kernel, estimate_rho, mean_formula, mean_intercept, scaled_lambda,
                            functional, functional_inputs, functional_parametrization, approximation,
                            basis_functions, boundary_factor, mean_centred,
                            discrepancy_parametrization, noise, noise_inputs, stochastic, biased_sources)
    if plan is None:
        plan = plan_scalar(data, simulator, method, options, program)
    else:
        _plan_alone(options, simulator=simulator, method=method, program=program)
    programs = plan.stan_programs()
    stan_backend = get_backend(backend)
    compile_s = stan_backend.compile(programs)  # 0.0: compiled earlier
    seed = command_seed(seed)
    new_points, fit_points, quadrature = _prediction_points(data, new_points, plan.l2)
    # a stage 1 the plan holds (reused by a gap's or an SBC's fits) cost nothing here
    emulator = plan.stage_one_result or run_stage_one(plan.stage_one, data, plan.options, programs,
                                                      backend=stan_backend, seed=seed) or {}
    stage_one_s = 0.0 if plan.stage_one_result else emulator.get("fit_s", 0.0)
    emulator = as_chain_starts(emulator) if plan.program.samples_emulator else emulator
    emulator = with_replicated_runs(emulator, data, emulates_runs=not plan.program.simulator)
    # theta against the model's own terms (simulator or stage 1's emulator), before any sampling
    plan, confounding = resolve_confounding(plan, data, stan_backend, emulator)
    sampler = replace(sampling, seed=seed).keywords()
    flat = programs[-1]
    fit, options, messages = _sample_checked(
        lambda options: _sample(stan_backend, flat, data, plan, options, fit_points, emulator, prior, sampler,
                                warm_start),
        data, plan, emulator, chosen_by_user=plan.basis_given, max_treedepth=max_treedepth)
    result = CalibrationResult(
        idata=fit.tree, data=data, method=plan.name, backend=stan_backend.name, options=options, program=flat,
        registry_row=plan.program,
        timing={"compile_s": compile_s,
                "sample_s": fit.sample.load_seconds + fit.sample.sample_seconds
                + stage_one_s},
        emulator=emulator, confounding=[c.to_json() for c in confounding])
    save_draws(result, out_dir)
    if quadrature is not None:
        logger.info("L2 calibration: projecting the draws of zeta onto the simulator")
        result = l2_result(result, quadrature, len(new_points))
    return check_fit(
        result, theta_names=data.theta_names, theta_widths=data.theta_upper - data.theta_lower,
        # L2's theta is a projection, not a density's
        log_density_functions=None if quadrature is not None else (
            lambda: stan_backend.log_density_functions(flat, fit.stan_json)),
        max_treedepth=max_treedepth, seed=seed,
        diagnosed=lambda names: [v for v in names if v in _DIAGNOSED or v in fit.parameter_names],
        advice=lambda d: parametrization_advice(options, d) + messages, out_dir=out_dir,
        runs_theta=data.runs[data.theta_names] if plan.program.runs else None)
