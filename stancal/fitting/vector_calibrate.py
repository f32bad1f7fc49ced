"""calibrate_vector(): KOH calibration of a vector output, from a
VectorCalibrationData to a VectorCalibrationResult. Two programs:
koh_vector.stan evaluates a cheap Stan simulator at every measured value;
modular_vector.stan emulates the runs in their reduced basis
(stancal.numerics.vector_emulator) and fixes that emulator after stage 1."""

from __future__ import annotations

import json
import logging
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import arviz_base as ab
import numpy as np
import pandas as pd
import xarray as xr

from stancal.results import diagnostics as sampler_checks
from stancal.results import modes as mode_checks
from stancal.stan.backends import get_backend
from stancal.fitting.inits import spread_theta_inits
from stancal.problem.mean_terms import MeanTerms, build_mean_terms
from stancal.stan.registry import Kernel, model_spec
from stancal.results.result import _AT_OBSERVATIONS  # the scalar programs' per-value quantities; both vector programs give them
from stancal.fitting.seeds import command_seed
from stancal.stan.source import FlatProgram, flatten
from stancal.results.summaries import posterior_table, summary_by_mode, theta_summary
from stancal.problem.vector_data import VectorCalibrationData
from stancal.numerics.vector_emulator import VectorEmulator

logger = logging.getLogger("stancal")

NOISE_MODES = {"known": 0, "one": 1, "per_experiment": 2}
# method -> (its name in results, its program); koh_emulator is modular_vector with joint = 1
METHODS = {"koh": ("koh_vector", "koh_vector"), "modular": ("modular_vector", "modular_vector"),
           "koh_emulator": ("koh_emulator_vector", "modular_vector")}
FROM_RUNS = ("modular", "koh_emulator")
PREDICTION_INDICES = 25  # per experiment, evenly over the index's range (one index column)


@dataclass(frozen=True)
class VectorOptions:
    """The model of one vector-output fit (what stancal.diagnosing.gap_location reads)."""

    method: str = "modular"
    discrepancy: str = "gp"
    noise: str = "one"
    kernel: str = "se"
    mean_formula: str | None = None
    mean_intercept: bool = False
    basis_functions: int = 0  # the vector programs' discrepancy is an exact GP

    @property
    def has_discrepancy(self) -> bool:
        return self.discrepancy == "gp"

    @property
    def kernel_id(self) -> int:
        return int(Kernel.SE if self.kernel == "se" else Kernel.MATERN52)


def choose_vector_method(data: VectorCalibrationData, simulator: str | Path | None, method: str | None) -> str:
    """koh with a Stan simulator, modular with runs only; a method that
    lacks what it needs is named."""
    method = method or ("koh" if simulator is not None else "modular")
    if method not in METHODS:
        raise ValueError(f"method '{method}' is not built for a vector output; choose one of {sorted(METHODS)}")
    if method == "koh" and simulator is None:
        raise ValueError("method 'koh' for a vector output needs a Stan simulator (simulator.stan)")
    if method in FROM_RUNS and data.basis is None:
        raise ValueError(f"method '{method}' for a vector output needs simulator runs (runs = ...)")
    return method


def vector_program(method: str, simulator: str | Path | None = None, program: str | Path | None = None) -> FlatProgram:
    aliases = {"simulator.stan": Path(simulator)} if simulator is not None and method == "koh" else {}
    return flatten(Path(program) if program else model_spec(METHODS[method][1]).path, aliases=aliases)


def prediction_rows(data: VectorCalibrationData, per_experiment: int = PREDICTION_INDICES) -> pd.DataFrame:
    """Rows where f, delta and zeta are drawn: per experiment, an even grid
    over the range of one index (the runs' grid, else the measured values'),
    or the runs' own grid (else the measured points) for a field; with the
    experiment's other columns, for mean terms."""
    grid = data.basis.grid if data.basis is not None else np.unique(data.physical[data.output_index].to_numpy(), axis=0)
    if grid.shape[1] == 1:
        indices = np.linspace(grid[:, 0].min(), grid[:, 0].max(), per_experiment)[:, None]
    else:
        indices = grid[np.unique(np.linspace(0, len(grid) - 1, min(len(grid), 4 * per_experiment)).astype(int))]
    first = data.source.groupby(data.experiment, sort=False).first().drop(columns=data.output_index)
    rows = [pd.DataFrame(indices, columns=data.output_index).assign(
                **{data.experiment: name, **first.loc[name].to_dict()}) for name in data.experiments.index]
    table = pd.concat(rows, ignore_index=True)
    return table[[data.experiment, *data.output_index, *[c for c in table if c != data.experiment
                                                         and c not in data.output_index]]]


def mean_terms(data: VectorCalibrationData, options: VectorOptions) -> MeanTerms | None:
    if options.mean_formula is None and not options.mean_intercept:
        return None
    return build_mean_terms(options.mean_formula, data.source, intercept=options.mean_intercept)


def fit_vector_emulator(data: VectorCalibrationData, seed: int) -> VectorEmulator:
    columns = [*data.inputs, *(p.name for p in data.all_parameters)]
    xt = data.scaling.to_unit(data.run_settings, columns)
    started = time.perf_counter()
    emulator = VectorEmulator.fit(data.basis, xt, data.run_outputs, seed)
    logger.info("stage 1: %s; one GP per component, hyperparameters at their posterior mode (scipy L-BFGS "
                "on %d of %d runs) in %.1f s", data.basis.describe(), emulator.hyperparameter_runs,
                len(xt), time.perf_counter() - started)
    return emulator


def _shared_stan_data(data: VectorCalibrationData, options: VectorOptions, new_rows: pd.DataFrame,
                      output_scale: float) -> dict[str, Any]:
    """What both vector programs take: experiments, noise, discrepancy switch,
    theta's bounds, the prediction rows' experiments."""
    if options.noise not in NOISE_MODES:
        raise ValueError(f"noise must be one of {sorted(NOISE_MODES)}; got '{options.noise}'")
    if options.noise == "known" and not data.noise_sd:
        raise ValueError("noise = 'known' needs the physical data's noise_sd column")
    if options.discrepancy not in ("gp", "none"):
        raise ValueError(f"discrepancy must be 'gp' or 'none' for a vector output; got '{options.discrepancy}'")
    physical = data.physical
    number = {name: e + 1 for e, name in enumerate(data.experiments.index)}
    unknown = sorted(set(new_rows[data.experiment].astype(str)) - set(number))
    if unknown:
        raise ValueError(f"prediction rows: experiment(s) {unknown[:5]} are not in the physical data, whose "
                         f"experiments carry the inputs and per-experiment theta the rows need")
    known = (physical[data.noise_sd].to_numpy() / output_scale) if data.noise_sd else np.zeros(len(physical))
    return dict(
        E=len(number), D=len(data.inputs), Q=len(data.parameters), Q_exp=len(data.per_experiment),
        N=len(physical), experiment=physical[data.experiment].map(number).to_numpy(),
        K_index=len(data.output_index), noise_mode=NOISE_MODES[options.noise], known_noise_sd=known,
        use_discrepancy=int(options.has_discrepancy),
        theta_lower=[p.lower for p in data.parameters], theta_upper=[p.upper for p in data.parameters],
        theta_exp_lower=[p.lower for p in data.per_experiment],
        theta_exp_upper=[p.upper for p in data.per_experiment],
        P=len(new_rows), experiment_new=new_rows[data.experiment].astype(str).map(number).to_numpy(),
        prior_only=0)


def _mean_term_data(terms: MeanTerms | None, rows: int, new_rows: pd.DataFrame) -> dict[str, Any]:
    """H, h, beta_prior_sd and h_new: no terms, or a formula's."""
    if terms is None:
        return dict(H=0, h=np.zeros((rows, 0)), beta_prior_sd=np.zeros(0), h_new=np.zeros((len(new_rows), 0)))
    return dict(H=len(terms.names), h=terms.h, beta_prior_sd=terms.prior_sd, h_new=terms.at(new_rows))


def koh_vector_data(data: VectorCalibrationData, options: VectorOptions, terms: MeanTerms | None,
                    new_rows: pd.DataFrame) -> dict[str, Any]:
    """koh_vector.stan's data."""
    scaling, physical = data.scaling, data.physical
    simulator_columns = [*data.inputs, *data.output_index]
    return dict(
        _shared_stan_data(data, options, new_rows, scaling.y_scale),
        **_mean_term_data(terms, len(physical), new_rows),
        D_cov=len(data.covariates), X=physical[simulator_columns].to_numpy(float),
        x_delta=scaling.to_unit(physical, data.discrepancy_inputs),
        y=scaling.standardise(physical[data.output].to_numpy()), y_center=scaling.y_center,
        y_scale=scaling.y_scale, kernel_id=options.kernel_id,
        X_new=new_rows[simulator_columns].to_numpy(float),
        x_delta_new=scaling.to_unit(new_rows, data.discrepancy_inputs))


def joint_inits(emulator: VectorEmulator) -> dict[str, Any]:
    """The joint fit starts its weight GPs at stage 1's hyperparameters."""
    hyper = [gp.hyperparameters for gp in emulator.components]
    return {"weight_gp_mean_free": [h.mean for h in hyper], "weight_gp_sd_free": [h.sd for h in hyper],
            "weight_gp_length_scale_free": [list(h.length_scale) for h in hyper],
            "weight_gp_nugget_free": [max(h.nugget, 1e-4) for h in hyper]}


def modular_vector_data(data: VectorCalibrationData, options: VectorOptions, emulator: VectorEmulator,
                        new_rows: pd.DataFrame, terms: MeanTerms | None = None) -> dict[str, Any]:
    """modular_vector.stan's data (joint = 1 for koh_emulator)."""
    physical, basis = data.physical, data.basis
    mean, components = basis.at(physical[data.output_index].to_numpy())
    mean_new, components_new = basis.at(new_rows[data.output_index].to_numpy())
    hyper = [gp.hyperparameters for gp in emulator.components]
    shared = _shared_stan_data(data, options, new_rows, basis.scale)
    return dict(
        shared, **_mean_term_data(terms, len(physical), new_rows),
        x=data.scaling.to_unit(data.experiments, data.inputs), D_cov=len(data.covariates),
        z=data.scaling.to_unit(data.experiments, data.covariates),
        index=data.scaling.to_unit(physical, data.output_index),
        y=(physical[data.output].to_numpy() - mean) / basis.scale, output_mean=mean, output_scale=basis.scale,
        C=basis.count, components=components, truncation_variance=basis.truncation_variance,
        M=len(emulator.xt_runs), xt_runs=emulator.xt_runs, joint=int(options.method == "koh_emulator"),
        run_weights=basis.weights(data.run_outputs),
        emulator_alpha=np.column_stack([gp.alpha for gp in emulator.components]),
        M_variance=len(emulator.variance_runs), variance_runs=emulator.variance_runs + 1,
        emulator_mean=[h.mean for h in hyper], emulator_sd=[h.sd for h in hyper],
        emulator_length_scale=np.array([h.length_scale for h in hyper]),
        emulator_nugget=[h.nugget for h in hyper],
        index_new=data.scaling.to_unit(new_rows, data.output_index), output_mean_new=mean_new,
        components_new=components_new)


@dataclass
class VectorCalibrationResult:
    idata: xr.DataTree
    data: VectorCalibrationData
    program: FlatProgram
    backend: str
    timing: dict[str, float]
    options: VectorOptions
    emulator: VectorEmulator | None = None  # stage 1 of modular
    terms: MeanTerms | None = None
    diagnostics: sampler_checks.Diagnostics | None = None
    modes: list = field(default_factory=list)

    @property
    def method(self) -> str:
        return METHODS[self.options.method][0]

    def theta_summary(self) -> dict[str, dict[str, float]]:
        """Shared theta's summary (stancal.results.summaries.theta_summary: modes
        weighed by their posterior mass, never blended)."""
        return theta_summary(self.idata["posterior"].to_dataset(), self.modes, self.data.theta_names)

    def summary(self) -> pd.DataFrame:
        """Every parameter, one block per theta mode when there are several."""
        return summary_by_mode(self.idata["posterior"].to_dataset(), self.modes)

    def to_summary_json(self) -> dict[str, Any]:
        d = self.diagnostics
        posterior = self.idata["posterior"]
        per_experiment = {}
        if self.data.per_experiment:
            table = posterior_table(posterior.to_dataset()[["theta_experiment"]])
            per_experiment = {f"{p.name}[{e}]": {k: float(table.loc[f"theta_experiment[{e}, {p.name}]", k])
                                                  for k in ("mean", "sd", "q05", "q95", "rhat")}
                              for e in self.data.experiments.index for p in self.data.per_experiment}
        basis = self.data.basis
        return {
            "method": self.method, "backend": self.backend,
            "theta": self.theta_summary(), "theta_per_experiment": per_experiment,
            "modes": [m.to_dict() for m in self.modes],
            "parameters": json.loads(self.summary().reset_index().to_json(orient="records")),
            "basis": None if self.emulator is None else {
                "components": basis.count, "explained": basis.explained.tolist(),
                "truncation_sd": float(basis.scale * np.sqrt(basis.truncation_variance)),
                "description": basis.describe()},
            "diagnostics": {"divergences": d.divergences, "max_rhat": d.max_rhat, "min_ess_bulk": d.min_ess_bulk,
                            "min_ess_tail": d.min_ess_tail, "treedepth_hits": d.treedepth_hits,
                            "warnings": d.messages},
            "timing": self.timing,
        }

    def save(self, path: str | Path) -> Path:
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        self.idata.to_netcdf(path)
        return path


def _datatree(draws: dict[str, np.ndarray], sample_stats: dict[str, np.ndarray], data: VectorCalibrationData,
              new_rows: pd.DataFrame, parameter_names: list[str], options: VectorOptions,
              terms: MeanTerms | None) -> xr.DataTree:
    """The posterior with named dimensions; the predictions as (experiment,
    output point) with the output index as coordinates; measured values
    along ``obs``."""
    names = list(data.experiments.index)
    per = len(new_rows) // len(names)
    # the default rows are one grid per experiment, in order: (experiment, output_point)
    on_grid = per * len(names) == len(new_rows) and (new_rows[data.experiment].to_numpy()
                                                      == np.repeat(names, per)).all()
    chains, draws_per_chain = draws["theta"].shape[:2]
    posterior = {"theta": draws["theta"]}
    if data.per_experiment:
        posterior["theta_experiment"] = draws["theta_experiment"]
    if options.noise == "per_experiment":
        posterior["noise_sd"] = draws["noise_sd_original"]
    elif options.noise == "one":
        posterior["noise_sd"] = draws["noise_sd_original"][..., 0]
    if options.has_discrepancy:
        posterior["delta_sd"] = draws["delta_sd_original"][..., 0]
    if draws["delta_length_scale"].shape[-1]:  # in each discrepancy input's own units
        widths = np.array([data.scaling.width[c] for c in data.discrepancy_inputs])
        posterior["delta_length_scale"] = draws["delta_length_scale"] * widths
    if options.method == "koh_emulator":  # the weight GPs' hyperparameters, sampled
        for name in ("mean", "sd", "length_scale", "nugget"):
            posterior[f"weight_gp_{name}"] = draws[f"weight_gp_{name}"]
    if terms is not None:  # each program's own output scale
        scale = data.basis.scale if options.method in FROM_RUNS else data.scaling.y_scale
        posterior["beta"] = draws["beta"] * scale / terms.scale
    shape = (len(names), per) if on_grid else (len(new_rows),)
    predictions = {k: draws[f"{k}_new"].reshape(chains, draws_per_chain, *shape) for k in ("f", "delta", "zeta")}
    dims = {"theta": ["theta_name"], "theta_experiment": ["experiment", "experiment_theta_name"],
            **{f"weight_gp_{n}": ["component"] for n in ("mean", "sd", "nugget")},
            "weight_gp_length_scale": ["component", "emulator_input"],
            "noise_sd": ["experiment"] if options.noise == "per_experiment" else [], "delta_length_scale": ["delta_input"], "beta": ["mean_term"],
            **{k: ["experiment", "output_point"] if on_grid else ["new_point"] for k in predictions}, "y": ["obs"],
            **{k: ["obs"] for k in _AT_OBSERVATIONS}}
    coords = {"theta_name": data.theta_names, "experiment": names,
              "experiment_theta_name": [p.name for p in data.per_experiment],
              "delta_input": data.discrepancy_inputs, "output_point": np.arange(per),
              "obs": np.arange(len(data.physical)), "mean_term": [] if terms is None else terms.names,
              "new_point": np.arange(len(new_rows)),
              "component": np.arange(1, data.basis.count + 1) if data.basis is not None else [],
              "emulator_input": [*data.inputs, *(p.name for p in data.all_parameters)]}
    groups = {"posterior": posterior, "predictions": predictions,
              "posterior_predictive": {"y": draws["y_rep"]}, "sample_stats": sample_stats}
    if "log_lik" in draws:
        groups["log_likelihood"] = {"y": draws["log_lik"]}
        groups["at_observations"] = {k: draws[k] for k in _AT_OBSERVATIONS}
    tree = ab.from_dict(groups, dims=dims, coords=coords, pred_dims=dims, pred_coords=coords)
    along = new_rows.iloc[:per] if on_grid else new_rows
    dim = "output_point" if on_grid else "new_point"
    extra = {} if on_grid else {data.experiment: (dim, new_rows[data.experiment].astype(str).to_numpy())}
    tree["predictions"] = xr.DataTree(tree["predictions"].to_dataset().assign_coords(
        {**{c: (dim, along[c].to_numpy()) for c in data.output_index}, **extra}))
    tree["observed_data"] = xr.DataTree(xr.Dataset(
        {"y": ("obs", data.physical[data.output].to_numpy()),
         data.experiment: ("obs", data.physical[data.experiment].to_numpy()),
         **{c: ("obs", data.physical[c].to_numpy()) for c in data.output_index}},
        coords={"obs": coords["obs"]}))
    tree["stan_parameters"] = xr.DataTree(ab.dict_to_dataset({k: draws[k] for k in parameter_names}))
    return tree


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
    posterior is written there as soon as sampling ends."""
    method = choose_vector_method(data, simulator, method)
    options = VectorOptions(method, discrepancy, noise or ("known" if data.noise_sd else "one"), kernel,
                            mean_formula, mean_intercept)
    if kernel not in ("se", "matern52"):
        raise ValueError(f"kernel must be 'se' or 'matern52'; got '{kernel}'")
    if method in FROM_RUNS and kernel != "se":
        raise ValueError("the runs' program (modular_vector.stan) has the squared-exponential discrepancy only")
    seed = command_seed(seed)
    flat = vector_program(method, simulator, program)
    stan_backend = get_backend(backend)
    stan_backend.compile([flat])
    new_rows = prediction_rows(data) if new_rows is None else new_rows
    terms = mean_terms(data, options)
    emulator = None
    if method in FROM_RUNS:  # stage 1: fixed by modular, the joint fit's starting point
        emulator = fit_vector_emulator(data, seed)
        stan_data = modular_vector_data(data, options, emulator, new_rows, terms)
    else:
        stan_data = koh_vector_data(data, options, terms, new_rows)
    inits = spread_theta_inits(chains, len(data.parameters), np.random.default_rng(seed))
    if method == "koh_emulator":
        for init in inits:
            init.update(joint_inits(emulator))
    logger.info("sampling %s: %d experiments, %d values%s; %d chains x (%d + %d)", METHODS[method][0],
                stan_data["E"], stan_data["N"], f", {stan_data['C']} components" if emulator else "",
                chains, warmup, draws)
    stan_json = {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in stan_data.items()}
    sample = stan_backend.sample(flat, stan_json, inits=inits, chains=chains, warmup=warmup, draws=draws,
                                 seed=seed, adapt_delta=adapt_delta, max_treedepth=max_treedepth)
    parameter_names = stan_backend.parameter_names(flat)
    tree = _datatree(sample.draws, sample.sample_stats, data, new_rows, parameter_names, options, terms)
    result = VectorCalibrationResult(tree, data, flat, stan_backend.name,
                                     {"compile_s": sample.compile_seconds, "sample_s": sample.sample_seconds},
                                     options, emulator, terms)
    if out_dir is not None:  # nothing below may lose the draws
        result.save(Path(out_dir) / "posterior.nc")
    posterior = tree["posterior"].to_dataset()
    result.modes, weights_unavailable = mode_checks.modes_of(
        tree, data.theta_names, np.array([p.upper - p.lower for p in data.parameters]),
        lambda: stan_backend.log_density_functions(flat, stan_json), seed)
    result.diagnostics = sampler_checks.check_sampler(
        posterior, tree["sample_stats"].to_dataset(), max_treedepth, list(posterior.data_vars),
        [m.chains for m in result.modes])
    sampler_checks.report(result.diagnostics)
    mode_checks.report(result.modes, weights_unavailable)
    if out_dir is not None:
        result.save(Path(out_dir) / "posterior.nc")
    return result
