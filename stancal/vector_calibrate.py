"""calibrate_vector(): modular KOH calibration of a vector output, from a
VectorCalibrationData to a VectorCalibrationResult (program
modular_vector.stan; the emulator of stancal.vector_emulator)."""

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

from . import diagnostics as sampler_checks
from . import modes as mode_checks
from .backends import get_backend
from .inits import spread_theta_inits
from .seeds import command_seed
from .models import model_spec
from .stan_source import FlatProgram, flatten
from .summaries import posterior_table, summary_by_mode, theta_summary
from .vector_data import VectorCalibrationData
from .vector_emulator import VectorEmulator

logger = logging.getLogger("stancal")

NOISE_MODES = {"known": 0, "one": 1, "per_experiment": 2}
PREDICTION_INDICES = 25  # per experiment, evenly over the runs' grid (one index column)


def prediction_rows(data: VectorCalibrationData, per_experiment: int = PREDICTION_INDICES) -> pd.DataFrame:
    """(experiment, index...) rows where f, delta and zeta are drawn: an even
    grid over the runs' range of one index, the runs' own grid for a field."""
    grid = data.basis.grid
    if grid.shape[1] == 1:
        indices = np.linspace(grid[:, 0].min(), grid[:, 0].max(), per_experiment)[:, None]
    else:
        indices = grid[np.unique(np.linspace(0, len(grid) - 1, min(len(grid), 4 * per_experiment)).astype(int))]
    rows = [pd.DataFrame(indices, columns=data.output_index).assign(**{data.experiment: name})
            for name in data.experiments.index]
    return pd.concat(rows, ignore_index=True)[[data.experiment, *data.output_index]]


def fit_vector_emulator(data: VectorCalibrationData, seed: int) -> VectorEmulator:
    columns = [*data.inputs, *(p.name for p in data.all_parameters)]
    xt = data.scaling.to_unit(data.run_settings, columns)
    started = time.perf_counter()
    emulator = VectorEmulator.fit(data.basis, xt, data.run_outputs, seed)
    logger.info("stage 1: %s; one GP per component, hyperparameters at their posterior mode (scipy L-BFGS "
                "on %d of %d runs) in %.1f s", data.basis.describe(), emulator.hyperparameter_runs,
                len(xt), time.perf_counter() - started)
    return emulator


def vector_stan_data(data: VectorCalibrationData, emulator: VectorEmulator, noise: str, discrepancy: str,
                     new_rows: pd.DataFrame) -> dict[str, Any]:
    """modular_vector.stan's data."""
    if noise not in NOISE_MODES:
        raise ValueError(f"noise must be one of {sorted(NOISE_MODES)}; got '{noise}'")
    if noise == "known" and not data.noise_sd:
        raise ValueError("noise = 'known' needs the physical data's noise_sd column")
    if discrepancy not in ("gp", "none"):
        raise ValueError(f"discrepancy must be 'gp' or 'none' for a vector output; got '{discrepancy}'")
    physical, basis = data.physical, data.basis
    names = list(data.experiments.index)
    number = {name: e + 1 for e, name in enumerate(names)}
    mean, components = basis.at(physical[data.output_index].to_numpy())
    mean_new, components_new = basis.at(new_rows[data.output_index].to_numpy())
    runs_xt = emulator.xt_runs
    hyper = [gp.hyperparameters for gp in emulator.components]
    known = (physical[data.noise_sd].to_numpy() / basis.scale) if data.noise_sd else np.zeros(len(physical))
    return dict(
        E=len(names), D=len(data.inputs), Q=len(data.parameters), Q_exp=len(data.per_experiment),
        N=len(physical), experiment=physical[data.experiment].map(number).to_numpy(),
        x=data.scaling.to_unit(data.experiments, data.inputs),
        K_index=len(data.output_index), index=data.scaling.to_unit(physical, data.output_index),
        y=(physical[data.output].to_numpy() - mean) / basis.scale, output_mean=mean, output_scale=basis.scale,
        C=basis.count, components=components, truncation_variance=basis.truncation_variance,
        noise_mode=NOISE_MODES[noise], known_noise_sd=known,
        use_discrepancy=int(discrepancy == "gp"),
        theta_lower=[p.lower for p in data.parameters], theta_upper=[p.upper for p in data.parameters],
        theta_exp_lower=[p.lower for p in data.per_experiment],
        theta_exp_upper=[p.upper for p in data.per_experiment],
        M=len(runs_xt), xt_runs=runs_xt, run_weights=basis.weights(data.run_outputs),
        emulator_mean=[h.mean for h in hyper], emulator_sd=[h.sd for h in hyper],
        emulator_length_scale=np.array([h.length_scale for h in hyper]),
        emulator_nugget=[h.nugget for h in hyper],
        P=len(new_rows), experiment_new=new_rows[data.experiment].map(number).to_numpy(),
        index_new=data.scaling.to_unit(new_rows, data.output_index), output_mean_new=mean_new,
        components_new=components_new, prior_only=0,
    )


@dataclass
class VectorCalibrationResult:
    idata: xr.DataTree
    data: VectorCalibrationData
    program: FlatProgram
    backend: str
    timing: dict[str, float]
    emulator: VectorEmulator  # stage 1
    diagnostics: sampler_checks.Diagnostics | None = None
    modes: list = field(default_factory=list)

    def theta_summary(self) -> dict[str, dict[str, float]]:
        """Shared theta's summary (stancal.summaries.theta_summary: modes
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
        return {
            "method": "modular_vector", "backend": self.backend,
            "theta": self.theta_summary(), "theta_per_experiment": per_experiment,
            "modes": [m.to_dict() for m in self.modes],
            "parameters": json.loads(self.summary().reset_index().to_json(orient="records")),
            "basis": {"components": self.data.basis.count, "explained": self.data.basis.explained.tolist(),
                      "truncation_sd": float(self.data.basis.scale * np.sqrt(self.data.basis.truncation_variance)),
                      "description": self.data.basis.describe()},
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
              new_rows: pd.DataFrame, parameter_names: list[str]) -> xr.DataTree:
    """The posterior with named dimensions; the predictions as (experiment,
    output point) with the output index as coordinates."""
    names = list(data.experiments.index)
    per = len(new_rows) // len(names)
    chains, draws_per_chain = draws["theta"].shape[:2]
    posterior = {"theta": draws["theta"]}
    if data.per_experiment:
        posterior["theta_experiment"] = draws["theta_experiment"]
    for name in ("noise_sd_original", "delta_sd_original"):
        if draws[name].shape[-1]:
            posterior[name.removesuffix("_original")] = draws[name] if draws[name].shape[-1] > 1 else draws[name][..., 0]
    if draws["delta_length_scale"].shape[-1]:  # in each input's and index's own units
        widths = np.array([data.scaling.width[c] for c in [*data.inputs, *data.output_index]])
        posterior["delta_length_scale"] = draws["delta_length_scale"] * widths
    predictions = {k: draws[f"{k}_new"].reshape(chains, draws_per_chain, len(names), per) for k in ("f", "delta", "zeta")}
    dims = {"theta": ["theta_name"], "theta_experiment": ["experiment", "experiment_theta_name"],
            "noise_sd": ["experiment"], "delta_length_scale": ["delta_input"],
            **{k: ["experiment", "output_point"] for k in predictions}, "y": ["value"]}
    coords = {"theta_name": data.theta_names, "experiment": names,
              "experiment_theta_name": [p.name for p in data.per_experiment],
              "delta_input": [*data.inputs, *data.output_index], "output_point": np.arange(per),
              "value": np.arange(len(data.physical))}
    tree = ab.from_dict({"posterior": posterior, "predictions": predictions,
                         "posterior_predictive": {"y": draws["y_rep"]}, "sample_stats": sample_stats},
                        dims=dims, coords=coords, pred_dims=dims, pred_coords=coords)
    first = new_rows.iloc[:per]
    tree["predictions"] = xr.DataTree(tree["predictions"].to_dataset().assign_coords(
        {c: ("output_point", first[c].to_numpy()) for c in data.output_index}))
    tree["observed_data"] = xr.DataTree(xr.Dataset(
        {"y": ("value", data.physical[data.output].to_numpy()),
         data.experiment: ("value", data.physical[data.experiment].to_numpy()),
         **{c: ("value", data.physical[c].to_numpy()) for c in data.output_index}},
        coords={"value": coords["value"]}))
    tree["stan_parameters"] = xr.DataTree(ab.dict_to_dataset({k: draws[k] for k in parameter_names}))
    return tree


def calibrate_vector(
    data: VectorCalibrationData,
    *,
    discrepancy: str = "gp",
    noise: str | None = None,
    program: str | Path | None = None,
    chains: int = 4,
    warmup: int = 1000,
    draws: int = 1000,
    seed: int | None = None,
    backend: str | None = None,
    adapt_delta: float = 0.9,
    max_treedepth: int = 10,
    out_dir: str | Path | None = None,
) -> VectorCalibrationResult:
    """Modular KOH for a vector output: stage 1 fits one GP per basis
    component to the runs; stage 2 samples theta (shared and per
    experiment), the discrepancy over (inputs, output index) and the noise.
    ``noise``: known (the data's noise_sd column; the default when it has
    one), one (one sd estimated) or per_experiment. ``program``: your copy
    of modular_vector.stan. ``out_dir``: the posterior is written there as
    soon as sampling ends."""
    if data.basis is None:
        raise ValueError("a vector-output calibration needs simulator runs (runs = ...)")
    if data.covariates:
        raise ValueError(f"covariates {data.covariates}: the vector-output discrepancy takes the simulator "
                         f"inputs and the output index only, so far")
    noise = noise or ("known" if data.noise_sd else "one")
    seed = command_seed(seed)
    flat = flatten(Path(program) if program else model_spec("modular_vector").path)
    stan_backend = get_backend(backend)
    stan_backend.compile([flat])
    emulator = fit_vector_emulator(data, seed)
    new_rows = prediction_rows(data)
    stan_data = vector_stan_data(data, emulator, noise, discrepancy, new_rows)
    inits = spread_theta_inits(chains, len(data.parameters), np.random.default_rng(seed))
    logger.info("sampling modular_vector: %d experiments, %d values, %d components; %d chains x (%d + %d)",
                stan_data["E"], stan_data["N"], stan_data["C"], chains, warmup, draws)
    stan_json = {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in stan_data.items()}
    sample = stan_backend.sample(flat, stan_json, inits=inits, chains=chains, warmup=warmup, draws=draws,
                                 seed=seed, adapt_delta=adapt_delta, max_treedepth=max_treedepth)
    parameter_names = stan_backend.parameter_names(flat)
    tree = _datatree(sample.draws, sample.sample_stats, data, new_rows, parameter_names)
    result = VectorCalibrationResult(tree, data, flat, stan_backend.name,
                                     {"compile_s": sample.compile_seconds, "sample_s": sample.sample_seconds},
                                     emulator)
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
