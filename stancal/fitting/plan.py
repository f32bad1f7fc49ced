"""The plan of a calibration: the program, its options and the user's files,
chosen once from the registry (stancal.stan.registry) and passed to every
later step, so that no step asks which program it runs."""

from __future__ import annotations

import logging
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any

from stancal.fitting.run_variance import require_replicates, run_replicates
from stancal.numerics.hsgp import first_basis
from stancal.numerics.parametrization import choose_parametrization
from stancal.problem.advice import config_key
from stancal.problem.data import CalibrationData
from stancal.problem.functional import check_functional
from stancal.problem.mean_terms import FormulaError, build_mean_terms
from stancal.problem.noise import check_noise, check_noise_inputs, noise_locations
from stancal.problem.options import EXACT_SIZE_LIMIT, RESTRICTED_DISCREPANCIES, ModelOptions, VectorOptions
from stancal.problem.source_bias import check_biased_sources
from stancal.problem.vector_data import VectorCalibrationData
from stancal.stan.registry import (
    L2,
    PROGRAMS,
    STAGE_ONE_FROM_RUNS,
    STAGE_ONE_PROGRAM,
    Program,
    default_program,
    fidelity_programs,
    for_method,
    stochastic_programs,
)
from stancal.stan.source import FlatProgram, flatten

logger = logging.getLogger("stancal")


@dataclass(frozen=True)
class Plan:
    """What runs: the registry's program, the model's options, the user's
    simulator and copy of the program, and whether theta is L2-projected."""

    program: Program
    options: ModelOptions | VectorOptions
    simulator: Path | None = None
    user_program: Path | None = None
    l2: bool = False
    basis_given: bool = False  # the Hilbert-space basis is the user's: checked, never rebuilt
    # theta checked against the model's own terms (stancal.fitting.confounding), once per plan
    confounding_checked: bool = False
    # the latent discrepancy's parametrisation is the user's: never refitted the other way
    parametrization_given: bool = False
    fidelities: int = 1  # simulators with runs: more than 1 with cheaper simulators' runs
    # stage 1's results, when every fit of this plan has the same runs (an SBC's simulations change y
    # only, a gap's refits drop physical rows only): reused, not refitted; only where stage 1 reads the
    # runs alone (stage_one_from_runs)
    stage_one_result: Any = field(default=None, compare=False, repr=False)  # a dict (scalar) or VectorEmulator

    @property
    def stage_one(self) -> str | None:
        """The kind of stage 1 that runs: the program's, or its multi-fidelity one."""
        return self.program.stage_one_fidelities if self.fidelities > 1 else self.program.stage_one

    @property
    def stage_one_from_runs(self) -> bool:
        """Stage 1 emulates the simulator from its runs alone (registry.STAGE_ONE_FROM_RUNS)."""
        return not self.program.simulator and self.stage_one in STAGE_ONE_FROM_RUNS

    @property
    def name(self) -> str:
        return self.program.name

    def stan_programs(self) -> list[FlatProgram]:
        """The flat programs to compile: stage 1's, if it runs one, then the main one."""
        helper = STAGE_ONE_PROGRAM.get(self.stage_one or "")
        return [flatten(PROGRAMS[helper].path), self.main_program()] if helper else [self.main_program()]

    def main_program(self) -> FlatProgram:
        """The program that samples: the user's copy or the shipped one, with the user's simulator."""
        aliases = {"simulator.stan": self.simulator} if self.simulator and self.program.simulator else {}
        return flatten(self.user_program or self.program.path, aliases=aliases)

    def with_simulator(self, simulator: Path) -> Plan:
        """The same model on a variant simulator written in Stan (the gap's candidates)."""
        base = default_program(self.program.output, simulator=True)
        version = base.latent_version if self.program.latent else (
            base.scalable_version if self.program.approximation == "hsgp" else None)
        chosen = PROGRAMS[version] if version else base
        return replace(self, program=chosen, simulator=Path(simulator), user_program=None, stage_one_result=None)


def model_options(discrepancy: str | None = None, kernel: str = "se", estimate_rho: bool = False,
                  mean_formula: str | None = None, mean_intercept: bool = False,
                  scaled_lambda: float | None = None, functional=(), functional_inputs=(),
                  functional_parametrization: str = "centred", approximation: str = "auto",
                  basis_functions=(), boundary_factor=(), mean_centred: bool = False,
                  discrepancy_parametrization: str = "auto", noise: str = "iid", noise_inputs=(),
                  stochastic: bool = False, biased_sources=()) -> ModelOptions:
    """calibrate()'s model keywords as ModelOptions; the discrepancy defaults
    to gp, or none with functional theta (flexible enough without one,
    review section 8.2)."""
    return ModelOptions("none" if discrepancy is None and functional else discrepancy or "gp", kernel,
                        estimate_rho, mean_formula, mean_intercept, scaled_lambda, tuple(functional),
                        tuple(functional_inputs), functional_parametrization, approximation,
                        tuple(basis_functions), tuple(boundary_factor), mean_centred,
                        discrepancy_parametrization, noise=noise, noise_inputs=noise_inputs,
                        stochastic=stochastic, biased_sources=biased_sources)


def make_plan(data: CalibrationData | VectorCalibrationData, simulator: str | Path | None = None,
              method: str | None = None, program: str | Path | None = None, **model) -> Plan:
    """The plan of a scalar or vector problem from calibrate()'s model keywords."""
    if isinstance(data, VectorCalibrationData):
        model.setdefault("noise", "known" if data.noise_sd else "one")
        return plan_vector(data, simulator, method, VectorOptions(**model), program)
    return plan_scalar(data, simulator, method, model_options(**model), program)


def model_keywords(options: dict, vector: bool) -> dict:
    """The keywords among ``options`` that describe the model (removed from it)."""
    names = [f.name for f in fields(VectorOptions if vector else ModelOptions)]
    return {k: options.pop(k) for k in names if k in options}


def latent_reason(data: CalibrationData, options: ModelOptions) -> str | None:
    """Why the latent-GP programs are needed (the outputs, or functional theta), or None."""
    return data.latent_reason or ("functional theta" if options.functional else None)


def require_gaussian(what: str, data: CalibrationData, options: ModelOptions | None = None) -> None:
    """The one guard of what works on the Gaussian programs only (their GP is
    integrated out): raise a ValueError that names ``what`` and the reason."""
    reason = latent_reason(data, options or ModelOptions())
    if reason:
        raise ValueError(f"{what} needs Gaussian, uncensored outputs and scalar theta; this problem "
                         f"has {reason}. Calibrate it with stancal calibrate")


def plan_scalar(data: CalibrationData, simulator: str | Path | None = None, method: str | None = None,
                options: ModelOptions | None = None, program: str | Path | None = None) -> Plan:
    """The user's method (or koh with a simulator, koh_emulator from runs),
    handed to its latent version when the outputs or theta need it, or to its
    scalable version above the exact programs' size; ``method = 'l2'``
    projects the zeta draws of that fit (Tuo & Wu 2015)."""
    options = options or ModelOptions()
    check_functional(data, options.functional, options.functional_inputs)
    l2 = method == L2
    if l2:
        require_gaussian("method 'l2'", data, options)
    base = _stochastic_base(data, simulator, method, options, _requested(data, simulator, None if l2 else method,
                                                                          "scalar"))
    chosen = _latent_version(base, latent_reason(data, options), options) or _scalable_version(data, base, options)
    _check_options(chosen, options)
    _check_noise(chosen, options, data)
    _check_mean_formula(data, options)
    if (l2 or options.discrepancy in RESTRICTED_DISCREPANCIES) and data.covariates:
        # both integrate over the box of the simulator's inputs (stancal.numerics.quadrature)
        raise ValueError(f"{'method l2' if l2 else f'discrepancy {options.discrepancy!r}'} integrates over the "
                         f"simulator inputs' box, so the discrepancy cannot take the covariates "
                         f"{data.covariates}; leave them out of the data, or use discrepancy 'gp'")
    basis_given = bool(options.basis_functions)
    parametrization_given = options.discrepancy_parametrization != "auto"
    options = _latent_parametrization(data, chosen, options)
    if chosen.approximation == "hsgp":
        options = replace(options, approximation="hsgp")
        if not options.basis_functions:
            basis = first_basis(options.kernel, data.discrepancy_inputs)
            options = replace(options, basis_functions=basis.counts, boundary_factor=basis.boundary_factors)
    _check_fidelities(data, chosen, options, method)
    _check_stochastic(data, chosen, options)
    return Plan(chosen, options, _path(simulator), _path(program), l2, basis_given,
                parametrization_given=parametrization_given, fidelities=data.fidelities if chosen.runs else 1)


def plan_vector(data: VectorCalibrationData, simulator: str | Path | None = None, method: str | None = None,
                options: VectorOptions | None = None, program: str | Path | None = None) -> Plan:
    """koh with a Stan simulator, modular with runs only; a method that
    lacks what it needs is named."""
    options = options or VectorOptions(noise="known" if data.noise_sd else "one")
    chosen = _requested(data, simulator, method, "vector")
    _check_options(chosen, options)
    _check_mean_formula(data, options)
    _check_fidelities(data, chosen, options, method)
    return Plan(chosen, options, _path(simulator), _path(program), fidelities=data.fidelities if chosen.runs else 1)


def _check_mean_formula(data, options: ModelOptions | VectorOptions) -> None:
    """The discrepancy's mean terms evaluate on the physical data, before
    anything compiles (the Stan data builds them again, for the fit)."""
    if options.mean_formula is None:
        return
    try:
        build_mean_terms(options.mean_formula, data.source, intercept=options.mean_intercept,
                         centred=getattr(options, "mean_centred", False))  # VectorOptions: never centred
    except FormulaError as err:
        raise FormulaError(f"[model] mean_formula: {err}") from None


def _path(value: str | Path | None) -> Path | None:
    return None if value is None else Path(value)


def _requested(data, simulator, method: str | None, output: str) -> Program:
    """The program a method names, checked for what it needs."""
    if method is None:
        if simulator is None and not data.has_runs:
            raise ValueError("give a Stan simulator, simulator runs, or both")
        return default_program(output, simulator=simulator is not None, fidelities=getattr(data, "fidelities", 1))
    chosen = for_method(method, output)
    if chosen.simulator and simulator is None:
        raise ValueError(f"method '{method}' needs a Stan simulator file" +
                         (" (simulator.stan)" if output == "vector" else ""))
    if chosen.runs and not data.has_runs:
        raise ValueError(f"method '{method}' needs simulator runs" + (" (runs = ...)" if output == "vector" else ""))
    return chosen


def _latent_version(base: Program, reason: str | None, options: ModelOptions) -> Program | None:
    """The latent-GP program that takes over, with what it cannot do named."""
    if reason is None:
        return None
    latent = base if base.latent else PROGRAMS[base.latent_version or ""] if base.latent_version else None
    if latent is None:
        raise ValueError(f"{reason} needs a latent-GP program, and method '{base.name}' has none")
    unsupported = [name for name, used in (
        (f"discrepancy '{options.discrepancy}'", options.discrepancy not in latent.discrepancies),
        ("estimate_rho", options.estimate_rho and not latent.estimate_rho),
        ("approximation 'hsgp'", options.approximation == "hsgp" and latent.approximation != "hsgp")) if used]
    if unsupported:
        raise ValueError(f"{reason} runs on the latent-GP programs, which do not support {', '.join(unsupported)}")
    return latent


def _latent_parametrization(data: CalibrationData, chosen: Program, options: ModelOptions) -> ModelOptions:
    """The latent programs' discrepancy GP centred, non-centred or partially
    non-centred, decided once: the user's choice, or the data's
    (stancal.numerics.parametrization, Papaspiliopoulos, Roberts & Sköld 2007;
    Christensen, Roberts & Sköld 2006), said in one line."""
    if not (chosen.latent and options.has_discrepancy) or options.discrepancy_parametrization_reason:
        return options
    if options.discrepancy_parametrization != "auto":
        return replace(options, discrepancy_parametrization_reason=(
            f"{options.discrepancy_parametrization} (set by the user: model.discrepancy_parametrization)"))
    x_delta = data.scaling.to_unit(data.physical, data.discrepancy_inputs)
    choice = choose_parametrization(data.observations, x_delta, len(data.inputs), options.kernel_id,
                                    partial=chosen.partial_centring)
    logger.info("the discrepancy's latent GP is sampled %s", choice.reason)
    return replace(options, discrepancy_parametrization=choice.parametrization,
                   discrepancy_parametrization_reason=choice.reason)


def dense_size(data: CalibrationData, program: Program) -> int:
    """The size of the dense matrix the exact program factorises at every
    gradient: the points, plus the runs for an emulator."""
    runs = data.run_count() if program.runs else 0
    return len(data.physical) + runs


def _scalable_version(data: CalibrationData, base: Program, options: ModelOptions) -> Program:
    """The scalable (hsgp) program when asked for, or under auto above
    EXACT_SIZE_LIMIT, said in one line. What it cannot do is an error, under
    auto too when the problem is above the limit: never a silent dense
    matrix of thousands of rows."""
    if base.approximation == "hsgp" or options.approximation == "exact" or base.scalable_version is None:
        return base
    scalable = PROGRAMS[base.scalable_version]
    size = dense_size(data, base)
    obstacles = [why for why, present in (
        (f"discrepancy '{options.discrepancy}' (needs the dense GP)",
         options.discrepancy not in scalable.discrepancies),
        (("covariates in the discrepancy (a Hilbert-space basis vanishes at its boundary, so it cannot "
         "switch a covariate off)"), options.has_discrepancy and len(data.discrepancy_inputs) > len(data.inputs)),
        ("low-fidelity runs", data.fidelities > 1 and base.runs and scalable.stage_one_fidelities is None),
    ) if present]
    if options.approximation == "hsgp":
        if obstacles:
            raise ValueError(f"approximation 'hsgp' does not support {'; '.join(obstacles)}. Use "
                             f"approximation = 'exact', or leave them out")
        return scalable
    if size <= EXACT_SIZE_LIMIT:
        return base
    runs = f" and {size - len(data.physical)} runs" if size > len(data.physical) else ""
    if obstacles:
        raise ValueError(f"{len(data.physical)} points{runs} exceed the exact programs' limit of "
                         f"{EXACT_SIZE_LIMIT}, but the scalable programs do not support {'; '.join(obstacles)}. "
                         f"Leave them out, or set approximation = 'exact' to run the dense GP anyway (slow)")
    logger.info("%d points%s: above %d, so %s runs (%s); approximation = 'exact' keeps the dense GP",
                len(data.physical), runs, EXACT_SIZE_LIMIT, scalable.name, scalable.description)
    return scalable


def _check_fidelities(data: CalibrationData | VectorCalibrationData, chosen: Program,
                      options: ModelOptions | VectorOptions, method: str | None) -> None:
    """Low-fidelity runs reach a program that takes them (said in one
    line), or name why not, before anything compiles."""
    if data.fidelities == 1 or not chosen.runs:  # a Stan simulator needs no runs of any fidelity
        return
    if chosen.stage_one_fidelities is None:
        takes = [p.name for p in fidelity_programs(chosen.output)]
        raise ValueError(f"method '{chosen.name}' does not take low-fidelity runs; {' or '.join(takes)} "
                         f"{'does' if len(takes) == 1 else 'do'} (review section 8.3), or leave "
                         f"[simulator.low_fidelity] out")
    if options.kernel != "se":
        raise ValueError(f"low-fidelity runs: the multi-fidelity emulator has the squared exponential kernel "
                         f"only; got kernel '{options.kernel}'")
    _check_fidelity_forms(data, chosen)
    logger.info("%d low-fidelity run set(s): the emulator is multi-fidelity (Kennedy & O'Hagan 2000), method "
                "'%s'%s", data.fidelities - 1, chosen.name, "" if method else " (the default with them)")


def _check_fidelity_forms(data: CalibrationData | VectorCalibrationData, chosen: Program) -> None:
    """What of the multi-fidelity emulator the chosen program takes (the
    registry's fidelity_* fields): the scale's form, a cheap level's own
    theta_l and the number of runs, each refusal one line naming the key and
    the programs that take it, before anything compiles."""
    def instead(what: str, can, fallback: str = "") -> str:
        takers = ", ".join(p.name for p in fidelity_programs(chosen.output) if can(p))
        if takers:
            return f"use method {takers}" + (f", or {fallback}" if fallback else "")
        return f"no method takes {what} for a {chosen.output} output yet" + (f": use {fallback}" if fallback else "")

    rho = data.low_fidelity_rho
    if rho not in chosen.fidelity_rho:
        raise ValueError(f"[simulator.low_fidelity] rho = {rho!r}: method '{chosen.name}' takes a scale of form "
                         f"{', '.join(chosen.fidelity_rho)} only; "
                         f"{instead(repr(rho), lambda p: rho in p.fidelity_rho, 'rho = \"constant\"')}")
    if data.theta_low_names and not chosen.fidelity_theta_low:
        raise ValueError(f"[simulator.low_fidelity.theta] (the cheap simulator's own {data.theta_low_names}): "
                         f"method '{chosen.name}' does not take it; "
                         f"{instead('theta_l', lambda p: p.fidelity_theta_low)}")
    runs = data.run_count()
    if chosen.fidelity_run_limit is not None and runs > chosen.fidelity_run_limit:
        raise ValueError(f"method '{chosen.name}' samples every level's emulator with theta for at most "
                         f"{chosen.fidelity_run_limit} runs of all fidelities; these are {runs}: "
                         f"{instead('them', lambda p: p.fidelity_run_limit is None)} (stage 1's hyperparameters, "
                         f"fixed)")


def _stochastic_base(data: CalibrationData, simulator, method: str | None, options: ModelOptions,
                     base: Program) -> Program:
    """A stochastic simulator is known by its runs: a Stan simulator is
    refused; without a method, the first program whose emulator takes its
    intrinsic variance (modular), said in one line."""
    if not options.stochastic:
        return base
    if simulator is not None:
        raise ValueError(f"{config_key('simulator', 'stochastic', True)} describes a simulator known by its runs; "
                         "a Stan simulator is a deterministic function of (x, theta): give the runs of the "
                         "stochastic simulator instead")
    if method is None and not base.stochastic_runs:
        base = stochastic_programs("scalar")[0]
        logger.info("a stochastic simulator: method '%s' (%s), the default with stochastic = true",
                    base.name, base.description)
    return base


def _check_stochastic(data: CalibrationData, chosen: Program, options: ModelOptions) -> None:
    """A stochastic simulator on a program that carries its intrinsic
    variance, with replicated runs to estimate it, before anything compiles."""
    if not options.stochastic:
        return
    if not chosen.stochastic_runs:
        taking = ", ".join(p.name for p in stochastic_programs("scalar"))
        raise ValueError(f"{config_key('simulator', 'stochastic', True)} runs on the programs {taking}; this "
                         f"problem runs {chosen.name} ({chosen.description})")
    if data.fidelities > 1:
        raise ValueError(f"{config_key('simulator', 'stochastic', True)} with low-fidelity runs is not built: "
                         "give the stochastic simulator's runs alone")
    require_replicates(run_replicates(data))


def _check_noise(chosen: Program, options: ModelOptions, data: CalibrationData) -> None:
    """The noise model against the data's columns and the chosen program
    (the registry's ``noises``), before anything compiles."""
    check_noise(options.noise, data.noise, options.biased_sources)
    check_noise_inputs(options.noise, options.noise_inputs, data.inputs)
    _check_biased_sources(chosen, options, data)
    if options.noise not in chosen.noises:
        taking = [p.name for p in PROGRAMS.values() if options.noise in p.noises and p.output == "scalar"]
        raise ValueError(f"noise {options.noise!r} runs on the programs {', '.join(taking)}; this problem "
                         f"runs {chosen.name} ({chosen.description}), which takes noise {', '.join(chosen.noises)} "
                         f"only")
    if data.noise.noise_sd_column and not chosen.known_noise_sd:
        taking = [p.name for p in PROGRAMS.values() if p.known_noise_sd]
        raise ValueError(f"a known noise sd (column '{data.noise.noise_sd_column}') runs on the programs "
                         f"{', '.join(taking)}; this problem runs {chosen.name} ({chosen.description})")
    noise_locations(data, options)  # heteroscedastic: each noise input varies over the physical rows


def _check_biased_sources(chosen: Program, options: ModelOptions, data: CalibrationData) -> None:
    """Biased sources (stancal.problem.source_bias) against the data's sources
    and the chosen program (the registry's ``source_biases``), before anything compiles."""
    if not options.biased_sources:
        return
    check_biased_sources(options.biased_sources, data.noise)
    if not chosen.source_biases:
        taking = [p.name for p in PROGRAMS.values() if p.source_biases]
        raise ValueError(f"biased_sources run on the programs {', '.join(taking)}; this problem runs "
                         f"{chosen.name} ({chosen.description})")


def _check_options(chosen: Program, options: ModelOptions | VectorOptions) -> None:
    """Options the chosen program cannot take, named before anything compiles."""
    if options.discrepancy not in chosen.discrepancies:
        needs = "method 'koh' (a simulator written in Stan)" if options.discrepancy in RESTRICTED_DISCREPANCIES \
            else f"one of {', '.join(chosen.discrepancies)}"
        raise ValueError(f"discrepancy '{options.discrepancy}' needs {needs}; got method '{chosen.name}'")
    if options.kernel not in chosen.kernels:
        raise ValueError(f"the program {chosen.stan_file} has the {' / '.join(chosen.kernels)} kernel only; "
                         f"got kernel '{options.kernel}'")
    if getattr(options, "estimate_rho", False) and not chosen.estimate_rho:
        raise ValueError(f"estimate_rho: {chosen.stan_file} has no rho")
    if getattr(options, "discrepancy_parametrization", "auto") == "partial" and not chosen.partial_centring:
        # any program: a Gaussian one integrates its GP out, so 'partial' would be silently ignored
        offered = [p.name for p in PROGRAMS.values() if p.partial_centring]
        raise ValueError(f"discrepancy_parametrization 'partial' is offered by {', '.join(offered)}, not by "
                         f"{chosen.name}; choose centred, non_centred or auto")
