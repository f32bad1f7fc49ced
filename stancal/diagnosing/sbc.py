"""Simulation-based calibration of a program with its sampler (Talts et
al. 2018; Modrák et al. 2023): draw parameters from the program's prior,
simulate data at the problem's design from the program itself, fit each
simulated data set, and test that the rank of every true value among its
posterior draws is uniform (stancal.diagnosing.sbc_ranks). The log-likelihood, a
function of the parameters and the data, is ranked too (Modrák et al.
2023): it reacts to a wrong likelihood that leaves each parameter's
marginal ranks nearly uniform.

The prior and the prior predictive come from the same program run with
``prior_only = 1`` (its y_rep), long enough that its evenly thinned draws
are nearly independent, as SBC's truths must be (Talts et al. 2018): a
hierarchical prior (Student-t's mixture weights under their degrees of
freedom) is a funnel that NUTS leaves slowly, and truths thinned from a
sticky stretch of its chain fail the rank test with no fit at fault
(_independent_prior); censored outputs are censored as the data were
(CalibrationData.with_output). Every fit keeps the original data's
standardisation: the programs' priors live on the standardised scale, so
re-standardising each simulated data set would fit a different prior from
the one simulated.

A vector output (VectorCalibrationData) goes the same way through
calibrate_vector: its y_rep are the replicated readings at each
experiment's output indices, put into a copy of the data by
VectorCalibrationData.with_output. The registry's commands say which
programs SBC takes (Program.commands); the others are refused before
anything compiles.
"""

from __future__ import annotations

import functools
import math
import time
import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from stancal.diagnosing.sbc_health import fit_health, fits_health, health_message
from stancal.diagnosing.sbc_ranks import Uniformity, fractional_ranks, rank_of, uniformity
from stancal.fitting.calibrate import calibrate
from stancal.fitting.cluster import FitFailure, FitRunner, FitTask, fit_runner
from stancal.fitting.plan import Plan, make_plan, model_keywords
from stancal.fitting.resume import Resume, keep_whole, write_json
from stancal.fitting.seeds import fit_seed
from stancal.fitting.vector_calibrate import calibrate_vector, prediction_rows
from stancal.problem import advice
from stancal.problem.data import CalibrationData
from stancal.problem.sampling import SamplerOptions
from stancal.problem.vector_data import VectorCalibrationData
from stancal.results.diagnostics import SamplerWarning
from stancal.results.result import CalibrationResult
from stancal.results.vector_result import VectorCalibrationResult
from stancal.stan.backends import get_backend
from stancal.stan.registry import SBC, commands_taking
from stancal.stan.standata import build_stan_data, to_stan_json
from stancal.stan.vector_standata import build_vector_stan_data

PRIOR_THINNING = 5  # the prior run's first length: 5 draws per simulation, evenly thinned to one
# the prior run is long enough when its smallest effective sample size is at least 2 per simulation: thinned
# to one draw per simulation, successive truths are then at least two autocorrelation times apart
PRIOR_ESS_PER_SIMULATION = 2
PRIOR_MAX_THINNING = 200  # and at most 200 draws per simulation
# each fit's defaults: many fits, each of a small posterior; the prior run's warm-up is SBC_WARMUP whatever
# the fits' (its draws' length is set by their ESS), so that longer fits refit the very same simulations
SBC_CHAINS, SBC_WARMUP = 2, 300
LOG_LIKELIHOOD = "log_likelihood"  # ranked beside the parameters (Modrák et al. 2023)
TRUTH = "truth.json"  # in each simulation's folder: the values it was simulated from
RANKED_DRAWS = "ranked_draws.json"  # and the thinned posterior draws they were ranked among


@dataclass
class SBCResult:
    simulations: int
    draws_per_fit: int
    ranks: dict[str, list[int]]  # parameter -> one rank per simulation
    tests: dict[str, Uniformity]
    seconds: float
    failed: list[int] = field(default_factory=list)  # simulations whose fit raised
    prior_run: dict[str, Any] = field(default_factory=dict)  # its draws and smallest ESS (_independent_prior)
    fits_health: dict[str, Any] = field(default_factory=dict)  # how the fits mixed (sbc_health.fits_health)

    def verdict(self, name: str) -> str:
        test = self.tests[name]
        return (f"{name}: ranks not uniform (p = {test.p_value:.3g} < {1 - test.level:.2g}): the program or the "
                f"sampler does not recover what it simulates" if test.rejected
                else f"{name}: ranks uniform at the {test.level:.0%} level (p = {test.p_value:.3g})")

    def to_json(self) -> dict[str, Any]:
        return {"simulations": self.simulations, "draws_per_fit": self.draws_per_fit,
                "parameters": {name: {"ranks": ranks, "p_value": self.tests[name].p_value,
                                      "rejected": self.tests[name].rejected, "verdict": self.verdict(name)}
                               for name, ranks in self.ranks.items()},
                "failed_simulations": self.failed, "prior_run": self.prior_run, "fits_health": self.fits_health,
                "seconds": round(self.seconds, 1)}


def _scalars(group, draw: int | None = None) -> dict[str, np.ndarray]:
    """Every scalar component of every variable: name[i, j] -> draws (or one draw)."""
    out = {}
    for name, variable in group.data_vars.items():
        values = np.asarray(variable).reshape(-1, *variable.shape[2:])
        extra = variable.dims[2:]
        for index in np.ndindex(*values.shape[1:]):
            labels = [str(variable.coords[d].values[i]) if d in variable.coords else str(i)
                      for d, i in zip(extra, index, strict=False)]
            key = f"{name}[{', '.join(labels)}]" if labels else name
            column = values[(slice(None), *index)]
            out[key] = column if draw is None else column[draw]
    return out


def _smallest_ess(prior_fit) -> tuple[float, str]:
    """The prior run's smallest effective sample size, bulk or tail, over
    every scalar SBC ranks that varies (a constant has none, and its truths
    are all alike), and that scalar's name."""
    import arviz_stats as ast
    import xarray as xr

    scalars = {name: values for name, values in _scalars(prior_fit.idata["prior"].to_dataset()).items()
               if np.ptp(values) > 0}
    if not scalars:
        return math.inf, "none"
    draws = xr.Dataset({name: (("chain", "draw"), values[None]) for name, values in scalars.items()})
    ess = {(name, kind): float(value) for kind in ("bulk", "tail")
           for name, value in ast.ess(draws, method=kind).data_vars.items()}
    (name, _), smallest = min(ess.items(), key=lambda item: item[1])
    return smallest, name


def _independent_prior(run_prior, simulations: int):
    """``run_prior(draws=...)`` run long enough that its draws, thinned to one
    per simulation, are nearly independent: while its smallest ESS is below
    PRIOR_ESS_PER_SIMULATION per simulation, again, longer by the shortfall
    (at most PRIOR_MAX_THINNING draws per simulation; short even then, a
    SamplerWarning says so). Returns the run and a record of it."""
    draws, needed, longest = PRIOR_THINNING * simulations, PRIOR_ESS_PER_SIMULATION * simulations, \
        PRIOR_MAX_THINNING * simulations
    while True:
        prior_fit = run_prior(draws=draws)
        ess, worst = _smallest_ess(prior_fit)
        if ess >= needed or draws >= longest:
            break
        draws = min(longest, math.ceil(1.25 * draws * needed / max(ess, 1.0)))
    if ess < needed:
        warnings.warn(f"SBC's prior run: {worst}'s effective sample size is {ess:.0f} in {draws} draws, below "
                      f"{needed} ({PRIOR_ESS_PER_SIMULATION} per simulation): its truths are not independent "
                      f"draws of the prior, and its ranks may be rejected with no fit at fault; reparametrise "
                      f"the prior (non-centred) or run fewer simulations", SamplerWarning, stacklevel=3)
    return prior_fit, {"draws": draws, "min_ess": round(ess, 1), "min_ess_of": worst}


def _thinned(values: np.ndarray, count: int) -> np.ndarray:
    return values[np.linspace(0, len(values) - 1, count).round().astype(int)]


def log_likelihood_draws(fit: CalibrationResult | VectorCalibrationResult) -> np.ndarray:
    """The fit program's log-likelihood (its log_lik summed over the
    observations) at every posterior draw."""
    return np.asarray(fit.idata["log_likelihood"]["y"]).reshape(-1, len(fit.data.physical)).sum(1)


def _fit_stan_data(fit: CalibrationResult | VectorCalibrationResult, functional_parametrization: str | None,
                   discrepancy_parametrization: str | None) -> dict[str, Any]:
    """The Stan data of a fit's program on its data: a vector output's with
    one prediction row per experiment (only log_lik is read), a scalar
    output's with its prediction points and the given parametrisations."""
    if isinstance(fit, VectorCalibrationResult):
        return build_vector_stan_data(fit.data, fit.row.data, fit.options, prediction_rows(fit.data, 1), fit.emulator)
    points = fit.idata["predictions_constant_data"].to_dataset().to_dataframe().reset_index(drop=True)
    options = replace(fit.options, functional_parametrization=functional_parametrization
                      or fit.options.functional_parametrization,
                      discrepancy_parametrization=discrepancy_parametrization
                      or fit.options.discrepancy_parametrization)
    return build_stan_data(fit.data, fit.row.data, options, points,
                           emulator_hyperparameters=fit.emulator.get("hyperparameters"))


def log_likelihood_at(fit: CalibrationResult | VectorCalibrationResult, parameters: dict[str, np.ndarray],
                       functional_parametrization: str | None = None,
                       discrepancy_parametrization: str | None = None) -> float:
    """The same log-likelihood on the fit's data at the program's own
    ``parameters`` (one draw, in ``functional_parametrization`` and
    ``discrepancy_parametrization`` if given: the prior's, which a fit may
    have left), through its generated quantities."""
    stan_data = _fit_stan_data(fit, functional_parametrization, discrepancy_parametrization)
    draws = get_backend(fit.backend).generate_quantities(
        fit.program, to_stan_json(stan_data), {k: np.asarray(v)[None, None] for k, v in parameters.items()}, seed=1)
    return float(draws["log_lik"].sum())


def functional_parametrizations(calibrate_options: dict[str, Any]) -> tuple[str | None, str | None]:
    """How a functional theta(x)'s GP is sampled for the prior and for the
    fits (None: no functional theta). Without data the hierarchical GP is a
    funnel that the centred form samples badly, and data drawn from the
    prior seldom pin theta(x), so both are non-centred unless the caller
    asks for another form of the fits."""
    if not calibrate_options.get("functional"):
        return None, None
    return "non_centred", calibrate_options.get("functional_parametrization", "non_centred")


def simulated_ranks(data: CalibrationData | VectorCalibrationData, truth: dict[str, float],
                    truth_parameters: dict[str, np.ndarray], draws_per_fit: int,
                    prior_parametrization: str | None = None, prior_discrepancy: str | None = None,
                    out_dir: str | Path | None = None,
                    **calibrate_options: Any) -> dict[str, dict]:
    """Fit one simulated data set and rank each true value among L evenly
    thinned posterior draws, and the log-likelihood at the truth among its
    values at those draws (run where the fit runs: only the ranks and the
    fit's sampler checks travel back, as {"ranks": ..., "health": ...}).
    In ``out_dir``, beside the fit: the truth (TRUTH) and the thinned draws
    each was ranked among (RANKED_DRAWS), so that a rank can be checked."""
    fit = _calibrate_for(data)(data, out_dir=out_dir, **calibrate_options)
    posterior = _scalars(fit.idata["posterior"].to_dataset())
    at_truth = {name: value for name, value in truth.items() if name in posterior}
    at_truth[LOG_LIKELIHOOD] = log_likelihood_at(fit, truth_parameters, prior_parametrization, prior_discrepancy)
    ranked = {name: _thinned(posterior[name], draws_per_fit) for name in at_truth if name != LOG_LIKELIHOOD}
    ranked[LOG_LIKELIHOOD] = _thinned(log_likelihood_draws(fit), draws_per_fit)
    if out_dir is not None:
        write_json(Path(out_dir) / TRUTH, {"values": {k: float(v) for k, v in at_truth.items()},
                                           "stan_parameters": {k: np.asarray(v).tolist()
                                                               for k, v in truth_parameters.items()}})
        write_json(Path(out_dir) / RANKED_DRAWS, {k: v.tolist() for k, v in ranked.items()})
    return {"ranks": {name: rank_of(at_truth[name], draws) for name, draws in ranked.items()},
            "health": fit_health(fit.diagnostics, fit.idata["posterior"].sizes["chain"])}


def _restored(task: FitTask, folder: Path, kept: dict) -> dict:
    """A finished simulation's record as simulated_ranks returns it; one
    written before SBC kept its fits' health holds the ranks alone."""
    return kept if set(kept) == {"ranks", "health"} else {"ranks": kept, "health": None}


def _sampling(calibrate_options: dict[str, Any], seed: int | None, draws_per_fit: int) -> SamplerOptions:
    """Each fit's sampler options, taken out of ``calibrate_options`` (chains,
    warmup and draws; the others stay for calibrate()) and checked before
    anything is compiled."""
    if not (isinstance(draws_per_fit, int) and draws_per_fit >= 1):
        raise ValueError(f"{advice.option('draws_per_fit')} must be a whole number of at least 1; "
                         f"got {draws_per_fit!r}")
    chains = calibrate_options.pop("chains", SBC_CHAINS)
    warmup = calibrate_options.pop("warmup", SBC_WARMUP)
    draws = calibrate_options.pop("draws", None)
    if draws is None:  # a bad chains is named by the check below, not met by a division
        draws = -(-2 * draws_per_fit // chains) if isinstance(chains, int) and chains >= 1 else 1
    sampling = SamplerOptions.from_keywords({**calibrate_options, "seed": seed, "chains": chains,
                                             "warmup": warmup, "draws": draws})
    if sampling.chains * sampling.draws < draws_per_fit:
        raise ValueError(f"{advice.option('draws')} x {advice.option('chains')} = "
                         f"{sampling.chains * sampling.draws} is fewer than the {draws_per_fit} draws per fit "
                         f"that are ranked ({advice.option('draws_per_fit')})")
    return sampling


def _calibrate_for(data: CalibrationData | VectorCalibrationData):
    """The calibration of the data's output kind: calibrate, or calibrate_vector."""
    return calibrate_vector if isinstance(data, VectorCalibrationData) else calibrate


def _require_sbc(plan: Plan) -> None:
    """Refuse, before anything compiles, a program the registry does not let SBC take."""
    if SBC not in plan.program.commands:
        takers = commands_taking(SBC, plan.program.output)
        raise ValueError(f"simulation-based calibration does not take program '{plan.name}' yet; for a "
                         f"{plan.program.output} output it takes {', '.join(takers) or 'none'}")


def _prior_draws(prior_fit, simulations: int, values: int) -> tuple[dict, dict, np.ndarray]:
    """S evenly thinned draws of the prior run: every scalar component, the
    program's own parameters, and the replicated outputs (``values`` each)."""
    prior = {k: _thinned(v, simulations) for k, v in _scalars(prior_fit.idata["prior"].to_dataset()).items()}
    parameters = {k: _thinned(np.asarray(v).reshape(v.shape[0] * v.shape[1], *v.shape[2:]), simulations)
                  for k, v in prior_fit.idata["prior_stan_parameters"].data_vars.items()}
    replicated = np.asarray(prior_fit.idata["prior_predictive"]["y"]).reshape(-1, values)
    return prior, parameters, _thinned(replicated, simulations)


def simulation_based_calibration(
    data: CalibrationData | VectorCalibrationData,
    *,
    simulator: str | Path | None = None,
    method: str | None = None,
    program: str | Path | None = None,
    simulations: int = 200,
    draws_per_fit: int = 100,
    level: float = 0.95,
    seed: int | None = None,
    out_dir: str | Path | None = None,
    scheduler: str | FitRunner | None = None,
    subset: list[int] | None = None,
    **calibrate_options: Any,
) -> SBCResult:
    """SBC of the program ``calibrate`` (``calibrate_vector`` for a
    VectorCalibrationData) runs on ``data`` (the design: its inputs and
    covariates, a vector output's experiments and output indices; its outputs
    are replaced by simulated ones).
    ``program``: fit with this program instead (e.g. a deliberately wrong
    copy) while simulating from the method's own. Each fit keeps
    ``draws_per_fit`` draws, evenly thinned from 2 x draws_per_fit over the chains.
    The fits run side by side on Dask (``scheduler``, see stancal.fitting.cluster).
    Under ``out_dir``, each simulation's folder holds its fit, its truth and
    the draws each truth was ranked among; a rerun with the same ``out_dir``
    reuses the simulations finished there (stancal.fitting.resume).
    ``calibrate_options`` (chains, warmup, discrepancy, ...) go to every fit
    (the prior run's warm-up is SBC_WARMUP, whatever the fits');
    ``draws`` per chain of each fit default to 2 x draws_per_fit over the chains.
    Every fit reuses the prior run's stage 1 where it reads the runs alone
    (the emulator's hyperparameters, which the simulations share), so it fits
    the program its data were simulated from, at a fraction of the cost: the
    SBC then checks stage 2 given stage 1, not stage 1's own randomness.
    ``subset``: fit only these of the S simulations, each with the truth, data
    and seed it has in the whole run (the prior run is the same), e.g. to
    refit some with longer chains: is a rejection the sampler's or the model's?
    A program the registry does not let SBC take is refused before anything compiles."""
    sampling = _sampling(calibrate_options, seed, draws_per_fit)
    fitted = _subset(subset, simulations)
    started = time.perf_counter()
    chains, warmup, per_chain = sampling.chains, sampling.warmup, sampling.draws
    prior_parametrization, fit_parametrization = functional_parametrizations(calibrate_options)
    vector = isinstance(data, VectorCalibrationData)
    model = model_keywords(calibrate_options, vector=vector)  # the plan's; the prior run's below
    prior_model = dict(model)
    if fit_parametrization:
        model["functional_parametrization"] = fit_parametrization
        prior_model["functional_parametrization"] = prior_parametrization
    if not vector:  # a latent discrepancy's prior without data: non-centred (centred is a funnel there)
        prior_model["discrepancy_parametrization"] = "non_centred"
    # one plan for every fit (simulated data sets share the design): its programs' code is part of each
    # fit's fingerprint
    plan = make_plan(data, simulator, method, program, **model)
    _require_sbc(plan)  # before the output folder is written to, and before anything compiles
    resume = Resume(out_dir, seed)  # a rerun into the same folder reuses the simulations it finished
    seed = resume.seed
    prior_fit, prior_run = _independent_prior(functools.partial(
        _calibrate_for(data), data, simulator=simulator, method=method, prior=True, chains=1, warmup=SBC_WARMUP,
        seed=seed, **calibrate_options, **prior_model), simulations)
    # the simulations share the runs, so a stage 1 from the runs alone (not the scalable one, which reads y)
    # is the prior's: each fit conditions on the hyperparameters its data were simulated with
    reused = prior_fit.emulator if plan.stage_one_from_runs and prior_fit.emulator else None
    plan = replace(plan, stage_one_result=reused)
    prior, prior_parameters, replicated = _prior_draws(prior_fit, simulations, len(data.physical))
    prior_discrepancy = getattr(prior_fit.options, "discrepancy_parametrization", None)  # scalar outputs' only
    tasks = [FitTask(f"simulation {s}", simulated_ranks, dict(
        data=data.with_output(replicated[s]), truth={name: float(v[s]) for name, v in prior.items()},
        truth_parameters={name: v[s] for name, v in prior_parameters.items()},
        prior_parametrization=prior_parametrization,
        prior_discrepancy=prior_discrepancy, draws_per_fit=draws_per_fit, plan=plan,
        chains=chains, warmup=warmup, draws=per_chain, seed=fit_seed(seed, f"simulation {s}"),
        out_dir=None if out_dir is None else Path(out_dir) / "fits" / f"{s:04d}", **calibrate_options))
        for s in fitted]
    with fit_runner(scheduler) as runner:
        runner.prepare([], calibrate_options.get("backend"))  # the prior's fit compiled the programs here
        outcomes = resume.map(runner, tasks, keep=keep_whole, restore=_restored)
    return _result(dict(zip(fitted, outcomes, strict=True)), draws_per_fit, level, seed, started, out_dir,
                   prior_run, sampling)


def _subset(subset: list[int] | None, simulations: int) -> list[int]:
    """The simulations fitted: all S, or the subset asked for (checked before anything compiles)."""
    if subset is None:
        fitted = list(range(simulations)) if isinstance(simulations, int) else []
    elif all(isinstance(s, int | np.integer) and 0 <= s < simulations for s in subset) and \
            len(set(subset)) == len(subset):
        fitted = [int(s) for s in subset]
    else:
        raise ValueError(f"subset must list distinct simulations from 0 to {simulations - 1}; got {list(subset)!r}")
    if len(fitted) < 2:  # the rank test compares an ECDF with the uniform one: one rank has none
        raise ValueError(f"SBC's rank test needs at least 2 simulations; got {len(fitted)} ({simulations!r} "
                         f"simulations{'' if subset is None else f', subset {list(subset)!r}'})")
    return fitted


def _result(outcomes: dict[int, Any], draws_per_fit: int, level: float, seed: int, started: float,
            out_dir: str | Path | None, prior_run: dict[str, Any], sampling: SamplerOptions) -> SBCResult:
    """Each parameter's ranks over the simulations that finished (by simulation
    number: their outcomes), their uniformity tests, the fits' health (a
    SamplerWarning says where they mixed poorly), and sbc.json."""
    ranks: dict[str, list[int]] = {}
    failed = [s for s, outcome in outcomes.items() if isinstance(outcome, FitFailure)]
    finished = [outcome for outcome in outcomes.values() if not isinstance(outcome, FitFailure)]
    for outcome in finished:
        for name, rank in outcome["ranks"].items():
            ranks.setdefault(name, []).append(rank)
    rng = np.random.default_rng(seed)
    tests = {name: uniformity(fractional_ranks(r, draws_per_fit, rng), level, seed) for name, r in ranks.items()}
    health = fits_health([outcome["health"] for outcome in finished])
    result = SBCResult(len(outcomes), draws_per_fit, ranks, tests, time.perf_counter() - started, failed, prior_run,
                       health)
    if out_dir is not None:
        Path(out_dir).mkdir(parents=True, exist_ok=True)
        write_json(Path(out_dir) / "sbc.json", result.to_json())
    message = health_message(health, sampling.warmup, sampling.draws)
    if message:  # after sbc.json is on disk: a caller that turns warnings into errors keeps the results
        warnings.warn(message, SamplerWarning, stacklevel=3)
    return result
