"""calibrate_vector(): KOH calibration of a vector output, from a
VectorCalibrationData to a VectorCalibrationResult. Two programs:
koh_vector.stan evaluates a cheap Stan simulator at every measured value;
modular_vector.stan emulates the runs in their reduced basis
(stancal.numerics.vector_emulator) and fixes that emulator after stage 1."""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from stancal.fitting.inits import StartMode, mode_inits, spread_theta_inits
from stancal.fitting.plan import Plan, plan_vector
from stancal.fitting.postfit import check_fit, save_draws
from stancal.fitting.seeds import command_seed
from stancal.fitting.simulator_check import check_simulator_at_start, explained
from stancal.fitting.stage_one import run_stage_one
from stancal.numerics.vector_emulator import VectorEmulator
from stancal.problem.options import VectorOptions
from stancal.problem.sampling import SamplerOptions
from stancal.problem.vector_data import VectorCalibrationData
from stancal.results.result import add_prior
from stancal.results.vector_result import VectorCalibrationResult, vector_datatree
from stancal.stan.backends import StanRuntimeError, get_backend
from stancal.stan.standata import to_stan_json
from stancal.stan.vector_standata import build_vector_stan_data, mean_terms

logger = logging.getLogger("stancal")

PREDICTION_INDICES = 25  # per experiment, evenly over the index's range (one index column)
# L-BFGS runs on the modular density where the joint fit starts (joint_start): a few seconds in all, and enough to
# find the mode from Stan's random inits (the cooling test's modular density has one other optimum, on a bound)
JOINT_START_OPTIMA = 8


def prediction_rows(data: VectorCalibrationData, per_experiment: int = PREDICTION_INDICES) -> pd.DataFrame:
    """Rows where f, delta and zeta are drawn: per experiment, an even grid
    over the range of one index (the runs' grid, else the measured values'),
    or the runs' own grid (else the measured points) for a field or for a
    few features (at most ``per_experiment``: a feature set's values lie at
    its points, not between them); with the experiment's other columns, for
    mean terms."""
    grid = data.basis.grid if data.basis is not None else np.unique(data.physical[data.output_index].to_numpy(), axis=0)
    if grid.shape[1] == 1 and len(grid) > per_experiment:
        indices = np.linspace(grid[:, 0].min(), grid[:, 0].max(), per_experiment)[:, None]
    else:
        indices = grid[np.unique(np.linspace(0, len(grid) - 1, min(len(grid), 4 * per_experiment)).astype(int))]
    first = data.source.groupby(data.experiment, sort=False).first().drop(columns=data.output_index)
    rows = [pd.DataFrame(indices, columns=data.output_index).assign(
                **{data.experiment: name, **first.loc[name].to_dict()}) for name in data.experiments.index]
    table = pd.concat(rows, ignore_index=True)
    return table[[data.experiment, *data.output_index, *[c for c in table if c != data.experiment
                                                         and c not in data.output_index]]]


def joint_inits(emulator: VectorEmulator) -> dict[str, Any]:
    """The joint fit starts its weight GPs at stage 1's hyperparameters."""
    hyper = [gp.hyperparameters for gp in emulator.components]
    return {"weight_gp_mean_free": [h.mean for h in hyper], "weight_gp_sd_free": [h.sd for h in hyper],
            "weight_gp_length_scale_free": [list(h.length_scale) for h in hyper],
            "weight_gp_nugget_free": [max(h.nugget, 1e-4) for h in hyper]}


def joint_start(stan_backend, program, stan_data: dict[str, Any], seed: int) -> dict[str, Any]:
    """Where every chain of the joint fit (koh_emulator) starts theta: the
    mode of the modular density, the same program with the weight GPs at
    stage 1's hyperparameters (feedback from the data to the emulator cut;
    Liu, Bayarri & Berger 2009, Bayesian Analysis 4(1)), the best of
    JOINT_START_OPTIMA L-BFGS runs. Chains spread over the theta box, as the
    other programs start, fall into modes of the joint posterior that the
    modular one lacks: at a theta the data rule out, the data bend the weight
    GPs (short length scales, nuggets ten times stage 1's) until the emulator
    is too unsure there to disagree. On the cooling test (40 runs, 4 x (500 +
    500)) two chains of four stayed in such modes, the runs' log likelihood
    110 to 160 below the main mode's, of posterior weight 0.000 (bridge
    sampling), and their own R-hat reached 1.035; the chains in the main mode
    mixed well (R-hat <= 1.007). Started at the modular mode, the joint fit
    keeps the emulator the runs show and samples its hyperparameters' spread
    about it (docs/vector.md); to look for separate theta modes, run modular,
    whose chains start spread."""
    modular = to_stan_json({**stan_data, "joint": 0})  # modular_vector.stan's switch: stage 1's weight GPs
    mode, _ = stan_backend.posterior_mode(program, modular, starts=JOINT_START_OPTIMA, seed=seed)
    # a backend may leave out a variable of size 0 (no per-experiment theta): Stan's inits then
    return {name: np.asarray(mode[name][0, 0]).tolist() for name in ("theta_unit", "theta_exp_unit") if name in mode}


def chain_inits(row, stan_backend, program, stan_data: dict[str, Any], emulator: VectorEmulator | None,
                chains: int, seed: int) -> tuple[list[dict[str, Any]], list[StartMode]]:
    """Where each chain starts, and the theta modes found before sampling
    (none when not searched): for the joint fit (the registry row samples
    the emulator) every chain at the modular mode with its weight GPs at
    stage 1's values (joint_start); for a row that starts at modes, in the
    modes of its own density within reach of the best (mode_inits); else
    theta spread over its box."""
    if row.samples_emulator:
        start = joint_start(stan_backend, program, stan_data, seed) | joint_inits(emulator)
        return [dict(start) for _ in range(chains)], []
    if row.starts_at_modes:
        return mode_inits(stan_backend, program, to_stan_json(stan_data), chains, int(stan_data["Q"]), seed)
    return spread_theta_inits(chains, int(stan_data["Q"]), np.random.default_rng(seed)), []


def calibrate_vector(
    data: VectorCalibrationData,
    *,
    simulator: str | Path | None = None,
    method: str | None = None,
    discrepancy: str = "gp",
    noise: str | None = None,
    kernel: str = "se",
    mean_formula: str | None = None,
    mean_intercept: bool = False,
    program: str | Path | None = None,
    new_rows: pd.DataFrame | None = None,
    chains: int = 4,
    warmup: int = 1000,
    draws: int = 1000,
    seed: int | None = None,
    backend: str | None = None,
    adapt_delta: float = 0.9,
    max_treedepth: int = 10,
    out_dir: str | Path | None = None,
    plan: Plan | None = None,
    prior: bool = False,
) -> VectorCalibrationResult:
    """KOH for a vector output. ``method``: koh (``simulator``, a Stan file
    with vector simulator(matrix X, vector theta), rows of X = (inputs...,
    output index...), evaluated at every measured value; the default when
    given), modular (stage 1 fits one GP per basis component to the runs;
    stage 2 samples theta with that emulator fixed) or koh_emulator (the
    components' GP hyperparameters sampled with theta, the runs' weights in
    the likelihood; for tens of runs, each step factors every component's
    runs covariance). Both sample theta
    (shared and per experiment), the discrepancy over (inputs, output index,
    covariates) and the noise.
    ``noise``: known (the data's noise_sd column; the default when it has
    one), one (one sd estimated) or per_experiment. ``mean_formula``: terms
    h' beta of the discrepancy mean over the physical columns.
    ``program``: your copy of the method's program. ``new_rows``: where f,
    delta and zeta are drawn (default: prediction_rows). ``out_dir``: the
    posterior is written there as soon as sampling ends. ``prior``: also draw
    from the prior (the same program, ``prior_only = 1``) into the ``prior``,
    ``prior_predictive`` and ``prior_stan_parameters`` groups, as calibrate()
    does (simulation-based calibration draws its truths there). A ``plan``
    holding stage 1's result (Plan.stage_one_result) reuses it."""
    SamplerOptions(chains, warmup, draws, seed, adapt_delta, max_treedepth)  # checked before anything else
    if plan is None:
        plan = plan_vector(data, simulator, method, VectorOptions(
            discrepancy, noise or ("known" if data.noise_sd else "one"), kernel, mean_formula, mean_intercept),
            program)
    options, row = plan.options, plan.program
    seed = command_seed(seed)
    flat = plan.main_program()
    stan_backend = get_backend(backend)
    compile_s = stan_backend.compile([flat])  # 0.0: compiled earlier
    new_rows = prediction_rows(data) if new_rows is None else new_rows
    emulator = plan.stage_one_result if plan.stage_one_result is not None else run_stage_one(
        plan.stage_one, data, options, [flat], backend=stan_backend, seed=seed)
    stan_data = build_vector_stan_data(data, row.data, options, new_rows, emulator)
    inits, start_modes = chain_inits(row, stan_backend, flat, stan_data, emulator, chains, seed)
    logger.info("sampling %s: %d experiments, %d values%s; %d chains x (%d + %d)", row.name,
                stan_data["E"], stan_data["N"], f", {stan_data['C']} components" if emulator else "",
                chains, warmup, draws)
    stan_json = to_stan_json(stan_data)
    # the simulator is called on each experiment's rows of (inputs, output index)
    simulator, points = plan.simulator if row.simulator else None, data.physical[[*data.inputs, *data.output_index]]
    check_simulator_at_start(stan_backend, flat, stan_json, inits, simulator, points)
    try:
        sample = stan_backend.sample(flat, stan_json, inits=inits, chains=chains, warmup=warmup, draws=draws,
                                     seed=seed, adapt_delta=adapt_delta, max_treedepth=max_treedepth)
    except StanRuntimeError as err:
        raise explained(err, simulator, points) from None
    terms = mean_terms(data, options)

    def datatree(drawn):
        return vector_datatree(drawn.draws, drawn.sample_stats, data, new_rows, stan_backend.parameter_names(flat),
                               options, terms, samples_emulator=row.samples_emulator, from_runs=row.runs)

    tree = datatree(sample)
    if prior:  # the same chains' starts and settings, another seed
        prior_tree = datatree(stan_backend.sample(
            flat, {**stan_json, "prior_only": 1}, inits=inits, chains=chains, warmup=warmup, draws=draws,
            seed=seed + 1, adapt_delta=adapt_delta, max_treedepth=max_treedepth))
        add_prior(tree, prior_tree)
    result = VectorCalibrationResult(tree, data, row.name, flat, stan_backend.name,
                                     {"compile_s": compile_s, "sample_s": sample.load_seconds + sample.sample_seconds},
                                     options, emulator, terms, start_modes=start_modes)
    save_draws(result, out_dir)
    return check_fit(result, theta_names=data.theta_names,
                     theta_widths=np.array([p.upper - p.lower for p in data.parameters]),
                     log_density_functions=lambda: stan_backend.log_density_functions(flat, stan_json),
                     max_treedepth=max_treedepth, diagnosed=lambda names: names, seed=seed, out_dir=out_dir,
                     runs_theta=data.run_settings[data.theta_names] if row.runs else None)
