"""The one registry of what can run: every Stan program stancal ships, what
it needs, what it takes, the parts of its Stan data, and which commands
accept it. A new program is one entry here; nothing outside this module
asks which program it is (the plan, stancal.fitting.plan, reads these rows).

Programs are chosen by method name and output kind: ``koh`` is koh.stan for
a scalar output and koh_vector.stan for a vector one. A program may hand its
job to another when the problem needs it: to its latent-GP version for
non-Gaussian or censored outputs and functional theta, and to its scalable
version for thousands of points and runs (review section 8.4)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from stancal.problem.noise import NOISES
from stancal.problem.options import RESTRICTED_DISCREPANCIES
from stancal.stan import standata as sd
from stancal.stan import vector_standata as vd
from stancal.stan.source import shipped_models_dir

# commands a program can be used by (besides calibrate, which takes all)
GAP, COMPARE, SBC, L2 = "gap", "compare", "sbc", "l2"
DESIGN = "design"  # `stancal design --criterion posterior`: the program of its theta posterior

# stage 1 kinds: how a program's emulator is fitted before sampling
STAGE_ONE_GP = "gp_emulator"  # emulator.stan's hyperparameters by optimisation
STAGE_ONE_SCALABLE = "scalable_emulator"  # stancal.numerics.scalable_emulator
STAGE_ONE_BASIS = "basis_emulator"  # stancal.numerics.vector_emulator: one GP per basis component
STAGE_ONE_FIDELITY = "fidelity_emulator"  # stancal.numerics.multifidelity: cheaper simulators' runs too
STAGE_ONE_BASIS_FIDELITY = "basis_fidelity_emulator"  # one multi-fidelity GP per basis component


@dataclass(frozen=True)
class Program:
    """One Stan program stancal ships, and everything stancal needs to run it."""

    name: str  # also the method name that reaches it directly
    stan_file: str
    description: str
    output: str = "scalar"  # scalar | vector
    methods: tuple[str, ...] = ()  # other method names that choose it, for its output kind
    simulator: bool = False  # includes the user's simulator.stan
    runs: bool = False  # needs simulator runs
    stage_one: str | None = None  # see STAGE_ONE_*
    stage_one_fidelities: str | None = None  # stage 1 with cheaper simulators' runs too (None: one fidelity only)
    # with cheaper simulators' runs: the most runs of all levels it takes (None: any number; the default
    # with them is a program without a limit), the forms of the scale between levels, and whether a cheap
    # level may have its own theta_l (Goh et al. 2013)
    fidelity_run_limit: int | None = None
    fidelity_rho: tuple[str, ...] = ("constant", "linear")
    fidelity_theta_low: bool = True
    latent: bool = False  # latent GPs at the data: counts, binomial, censored, functional theta
    approximation: str = "exact"  # exact | hsgp
    discrepancies: tuple[str, ...] = ("gp", "none")
    noises: tuple[str, ...] = ("iid",)  # measurement noise models (stancal.problem.noise); vector: unused
    known_noise_sd: bool = False  # takes each row's known noise sd (functions/noise.stan)
    kernels: tuple[str, ...] = ("se", "matern52")
    estimate_rho: bool = True  # can scale the simulator by rho
    latent_version: str | None = None  # takes over for latent problems
    scalable_version: str | None = None  # takes over above the exact programs' size limit
    data: tuple[Callable[..., dict[str, Any]], ...] = ()  # Stan data parts, merged in order
    samples_emulator: bool = False  # the emulator's hyperparameters are sampled with theta
    stochastic_runs: bool = False  # its emulator carries a stochastic simulator's intrinsic variance
    starts_at_modes: bool = False  # chains start in theta's modes, found by L-BFGS (fitting.inits.mode_inits)
    commands: frozenset[str] = frozenset()
    helper: bool = False  # a stage-1 program, not a calibration

    @property
    def partial_centring(self) -> bool:
        """Its latent discrepancy can be sampled partially non-centred
        (delta_centred 2): its Stan data carry the data's information per point."""
        return sd.partial_centring in self.data

    @property
    def source_biases(self) -> bool:
        """Its Gaussian likelihood takes biased measurement sources: a bias GP per
        biased source beside the discrepancy (functions/source_bias.stan)."""
        return sd.source_biases in self.data

    @property
    def path(self) -> Path:
        """The program's file: shipped, or a user's copy given by its absolute path."""
        path = Path(self.stan_file)
        return path if path.is_absolute() else shipped_models_dir() / path


# koh_emulator with cheaper simulators' runs: every gradient factorises the joint covariance of all
# runs and readings, with one kernel and its gradients per level (docs/multifidelity.md measures the cost)
JOINT_FIDELITY_RUN_LIMIT = 200

_SCALAR = frozenset({GAP, COMPARE, SBC})
_GAUSSIAN = (sd.common_data, sd.gaussian_outputs)
_NOISY = {"noises": NOISES, "known_noise_sd": True}  # the exact Gaussian programs: functions/noise.stan
_NOISE_DATA = (sd.noise_model, sd.source_biases)  # their noise, and biased sources (functions/source_bias.stan)
_LATENT = (sd.common_data, sd.latent_outputs)

PROGRAMS: dict[str, Program] = {program.name: program for program in (
    Program("koh", "koh.stan", "KOH with a cheap simulator written in Stan", simulator=True,
            discrepancies=("gp", "none", *RESTRICTED_DISCREPANCIES), latent_version="koh_latent",
            scalable_version="koh_hsgp", data=(*_GAUSSIAN, *_NOISE_DATA, sd.simulator_points,
                                               sd.restricted_discrepancy), commands=_SCALAR | {L2}, **_NOISY),
    Program("koh_emulator", "koh_emulator.stan", "full KOH: emulator and calibration in one joint GP",
            runs=True, latent_version="koh_latent_emulator", scalable_version="modular_hsgp",
            # with cheaper simulators' runs, stage 1's estimates start the chains; every level's GP is sampled
            stage_one_fidelities=STAGE_ONE_FIDELITY, fidelity_run_limit=JOINT_FIDELITY_RUN_LIMIT,
            fidelity_rho=("constant",), fidelity_theta_low=False,
            data=(*_GAUSSIAN, *_NOISE_DATA, sd.sampled_fidelity_runs), samples_emulator=True,
            commands=_SCALAR | {L2}, **_NOISY),
    Program("emulator", "emulator.stan", "GP emulator of simulator runs (stage 1 of modular)", runs=True,
            helper=True),
    Program("modular", "modular.stan", "modular KOH: stage 2 with the stage-1 emulator fixed", runs=True,
            stage_one=STAGE_ONE_GP, stage_one_fidelities=STAGE_ONE_FIDELITY, latent_version="koh_latent_emulator",
            scalable_version="modular_hsgp",
            data=(*_GAUSSIAN, *_NOISE_DATA, sd.emulator_points, sd.fidelity_emulator),
            commands=_SCALAR | {L2, DESIGN}, stochastic_runs=True, **_NOISY),
    Program("koh_latent", "koh_latent.stan",
            "KOH with latent GPs: counts, binomial, censored outputs, functional theta", simulator=True,
            latent=True, estimate_rho=False, data=(*_LATENT, sd.simulator_points, sd.partial_centring),
            commands=_SCALAR),
    Program("koh_latent_emulator", "koh_latent_emulator.stan",
            "koh_latent from simulator runs: stage-1 emulator on the link scale, latent at the data", runs=True,
            stage_one=STAGE_ONE_GP, latent=True, estimate_rho=False,
            data=(*_LATENT, sd.emulator_inputs, sd.fixed_emulator), commands=_SCALAR),
    Program("koh_hsgp", "koh_hsgp.stan", "koh for thousands of points: Hilbert-space GP discrepancy",
            simulator=True, approximation="hsgp",
            data=(*_GAUSSIAN, sd.hsgp_discrepancy, sd.simulator_points), commands=_SCALAR),
    Program("modular_hsgp", "modular_hsgp.stan",
            "modular for thousands of runs and points: precomputed-weight emulator, Hilbert-space GP discrepancy",
            runs=True, stage_one=STAGE_ONE_SCALABLE, approximation="hsgp",
            data=(*_GAUSSIAN, sd.hsgp_discrepancy, sd.scalable_emulator), commands=_SCALAR, stochastic_runs=True),
    Program("koh_vector", "koh_vector.stan",
            "KOH for a vector output with a cheap Stan simulator, ragged experiments", output="vector",
            methods=("koh",), simulator=True, estimate_rho=False, data=(vd.simulator_at_values,),
            commands=frozenset({GAP, SBC})),
    Program("modular_vector", "modular_vector.stan",
            "modular KOH for a vector output: one emulator GP per basis component, ragged experiments",
            output="vector", methods=("modular",), runs=True, stage_one=STAGE_ONE_BASIS,
            stage_one_fidelities=STAGE_ONE_BASIS_FIDELITY, fidelity_rho=("constant",), fidelity_theta_low=False,
            kernels=("se",), estimate_rho=False, data=(vd.basis_emulator, vd.modular_weights),
            commands=frozenset({GAP, DESIGN, SBC}),
            starts_at_modes=True),
    Program("koh_emulator_vector", "modular_vector.stan",
            "koh_emulator for a vector output: the basis weights' GP hyperparameters sampled with theta",
            output="vector", methods=("koh_emulator",), runs=True, stage_one=STAGE_ONE_BASIS, kernels=("se",),
            estimate_rho=False, data=(vd.basis_emulator, vd.joint_weights), samples_emulator=True,
            commands=frozenset({GAP})),
)}
MODELS = PROGRAMS  # the name of the registry in stancal's first releases
STAGE_ONE_PROGRAM = {STAGE_ONE_GP: "emulator"}  # stage 1 kinds that run a Stan program
# stage 1 kinds that read the runs alone, not the readings (the scalable one reads y): fits that change y only
# (an SBC's simulations) can share one stage 1
STAGE_ONE_FROM_RUNS = frozenset({STAGE_ONE_GP, STAGE_ONE_FIDELITY, STAGE_ONE_BASIS, STAGE_ONE_BASIS_FIDELITY})


@dataclass(frozen=True)
class Estimator:
    """A way of estimating theta that `stancal compare` sets side by side
    (review section 6): the problem's default fit (KOH), that fit's zeta
    draws projected onto the simulator (L2, Tuo & Wu 2015), or a program
    with a discrepancy restricted to keep theta identifiable."""

    name: str
    method: str | None = None  # None: the problem's default program
    discrepancy: str | None = None
    projects: bool = False  # theta = the L2 projection of the default fit's zeta draws


DEFAULT_ESTIMATOR = "koh"
ESTIMATORS: dict[str, Estimator] = {e.name: e for e in (
    Estimator(DEFAULT_ESTIMATOR), Estimator(L2, projects=True),
    *(Estimator(form, "koh", form) for form in RESTRICTED_DISCREPANCIES))}


def program(name: str) -> Program:
    """The registry row of a program (or the method name of its scalar output)."""
    try:
        return PROGRAMS[name]
    except KeyError:
        raise ValueError(f"unknown program {name!r}; choose one of {', '.join(PROGRAMS)}") from None


def method_names(output: str) -> list[str]:
    """The method names a user can give for an output kind."""
    names = [name for p in PROGRAMS.values() if p.output == output and not p.helper
             for name in (p.name, *p.methods)]
    return list(dict.fromkeys(names))


def entry_methods(output: str) -> list[str]:
    """The methods a user picks among: every program that is not a stage-1
    helper nor another program's latent or scalable version."""
    derived = {name for p in PROGRAMS.values() for name in (p.latent_version, p.scalable_version) if name}
    return [p.name if p.output == "scalar" else p.methods[0] for p in PROGRAMS.values()
            if p.output == output and not p.helper and p.name not in derived]


def for_method(method: str, output: str) -> Program:
    """The program a method name chooses for an output kind."""
    for row in PROGRAMS.values():
        if row.output == output and not row.helper and method in (row.name, *row.methods):
            return row
    raise ValueError(f"method '{method}' is not built for a {output} output; choose one of "
                     f"{', '.join(method_names(output))}")


def default_program(output: str, *, simulator: bool, fidelities: int = 1) -> Program:
    """koh with a Stan simulator, else the runs' default: koh_emulator for a
    scalar output, modular for a vector one; with runs of cheaper simulators
    too, the first of those that takes them at any number of runs."""
    chosen = for_method("koh" if simulator else "koh_emulator" if output == "scalar" else "modular", output)
    if fidelities > 1 and not simulator and (chosen.stage_one_fidelities is None
                                             or chosen.fidelity_run_limit is not None):
        return [p for p in fidelity_programs(output) if p.fidelity_run_limit is None][0]
    return chosen


def stochastic_programs(output: str) -> list[Program]:
    """The programs of an output kind whose emulator takes a stochastic simulator's runs."""
    return [p for p in PROGRAMS.values() if p.output == output and p.stochastic_runs]


def fidelity_programs(output: str) -> list[Program]:
    """The programs of an output kind that take runs of cheaper simulators too."""
    return [p for p in PROGRAMS.values() if p.output == output and p.stage_one_fidelities]


def commands_taking(command: str, output: str) -> list[str]:
    """The programs of an output kind that a command (gap, compare, sbc, l2) takes."""
    return [p.name for p in PROGRAMS.values() if command in p.commands and p.output == output]


def register(row: Program) -> Program:
    """Add a program (a user's copy of a shipped one, say) under a new name."""
    if row.name in PROGRAMS:
        raise ValueError(f"a program named {row.name!r} is registered already")
    PROGRAMS[row.name] = row
    return row
