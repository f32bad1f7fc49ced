"""The result of a vector-output calibration: an ArviZ DataTree with the
predictions per (experiment, output point), and its summaries."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import arviz_base as ab
import numpy as np
import pandas as pd
import xarray as xr

from stancal.numerics.vector_emulator import VectorEmulator
from stancal.problem.mean_terms import MeanTerms
from stancal.problem.options import VectorOptions
from stancal.problem.vector_data import VectorCalibrationData
from stancal.results import diagnostics as sampler_checks
from stancal.results.result import (
    AT_OBSERVATIONS,  # the scalar programs' per-value quantities; both vector programs give them
)
from stancal.results.summaries import posterior_table, summary_by_mode, theta_summary
from stancal.stan.registry import Program, program
from stancal.stan.source import FlatProgram


@dataclass
class VectorCalibrationResult:
    idata: xr.DataTree
    data: VectorCalibrationData
    method: str  # the program's name in the registry
    program: FlatProgram
    backend: str
    timing: dict[str, float]
    options: VectorOptions
    emulator: VectorEmulator | None = None  # stage 1 of modular
    terms: MeanTerms | None = None
    diagnostics: sampler_checks.Diagnostics | None = None
    modes: list = field(default_factory=list)
    # theta's modes found by L-BFGS before sampling, where the chains started (stancal.fitting.inits.StartMode)
    start_modes: list = field(default_factory=list)

    @property
    def row(self) -> Program:
        """The registry row of the program that made this result."""
        return program(self.method)

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
            # the optima found before sampling, those far below the best (no chain) among them
            "start_modes": [m.to_dict(self.data.parameters) for m in self.start_modes],
            "parameters": json.loads(self.summary().reset_index().to_json(orient="records")),
            "basis": None if self.emulator is None else {
                "components": basis.count, "explained": basis.explained.tolist(),
                # the errors the likelihood adds, independent, original units: truncation at every value,
                # interpolation at the values off the runs' grid (OutputBasis.independent_variance_at)
                "truncation_sd": float(basis.scale * np.sqrt(basis.truncation_variance)),
                "interpolation_sd": float(basis.scale * np.sqrt(basis.interpolation_variance)),
                "values_off_grid": int((basis.independent_variance_at(
                    self.data.physical[self.data.output_index].to_numpy()) > basis.truncation_variance).sum()),
                "values": len(self.data.physical),
                "description": basis.describe(),
                # runs of cheaper simulators: per component, rho and what they add (docs/multifidelity.md)
                "fidelity": self.emulator.fidelity_summary()},
            "diagnostics": d.summary(),
            "timing": self.timing,
        }

    def save(self, path: str | Path) -> Path:
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        self.idata.to_netcdf(path)
        return path


def vector_datatree(draws: dict[str, np.ndarray], sample_stats: dict[str, np.ndarray], data: VectorCalibrationData,
                    new_rows: pd.DataFrame, parameter_names: list[str], options: VectorOptions,
                    terms: MeanTerms | None, *, samples_emulator: bool, from_runs: bool) -> xr.DataTree:
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
    if samples_emulator:  # the weight GPs' hyperparameters, sampled
        for name in ("mean", "sd", "length_scale", "nugget"):
            posterior[f"weight_gp_{name}"] = draws[f"weight_gp_{name}"]
    if terms is not None:  # each program's own output scale
        scale = data.basis.scale if from_runs else data.scaling.y_scale
        posterior["beta"] = draws["beta"] * scale / terms.scale
    shape = (len(names), per) if on_grid else (len(new_rows),)
    predictions = {k: draws[f"{k}_new"].reshape(chains, draws_per_chain, *shape) for k in ("f", "delta", "zeta")}
    dims = {"theta": ["theta_name"], "theta_experiment": ["experiment", "experiment_theta_name"],
            **{f"weight_gp_{n}": ["component"] for n in ("mean", "sd", "nugget")},
            "weight_gp_length_scale": ["component", "emulator_input"],
            "noise_sd": ["experiment"] if options.noise == "per_experiment" else [],
            "delta_length_scale": ["delta_input"], "beta": ["mean_term"],
            **{k: ["experiment", "output_point"] if on_grid else ["new_point"] for k in predictions}, "y": ["obs"],
            **{k: ["obs"] for k in AT_OBSERVATIONS}}
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
        groups["at_observations"] = {k: draws[k] for k in AT_OBSERVATIONS}
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
