"""The result of a calibration: an ArviZ DataTree plus what is needed to
summarise it on the original scale and to predict at new points."""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import xarray as xr

from stancal.numerics.noise_gp import log_scale_at
from stancal.problem.data import CalibrationData
from stancal.problem.functional import functional_grid
from stancal.problem.noise import (
    OUTLIER_WEIGHT,
    NoiseLocations,
    describes_noise,
    noise_input_names,
    noise_locations,
    outlier_rows,
    replicate_counts,
)
from stancal.problem.options import ModelOptions
from stancal.results.diagnostics import Diagnostics
from stancal.results.modes import Mode
from stancal.results.summaries import band, summary_by_mode, theta_function_summary, theta_summary
from stancal.stan.backends.base import Draws, SampleOutput
from stancal.stan.registry import Program, program
from stancal.stan.source import FlatProgram
from stancal.stan.standata import EMULATOR_HYPERPARAMETERS, mean_terms_of

# Stan program variables -> names in the posterior group (original units)
_REPORTED = {
    "theta": "theta",
    "theta_low": "theta_low",  # the cheap simulator's own theta_l (Goh et al. 2013)
    "noise_sd_original": "noise_sd",
    "delta_sd_original": "delta_sd",
    "rho": "rho",
    "phi": "phi",
    "nu": "nu",
    "noise_gp_sd": "noise_gp_sd",
}
# some programs declare these as arrays: of size 0 or 1 (present or not; delta_sd,
# phi, nu), or noise_sd of size S (koh, koh_emulator, modular: one per measurement
# source with noise = "per_source", kept per source then; size 1 becomes a scalar)
_OPTIONAL_SCALARS = ("noise_sd", "delta_sd", "phi", "nu", "noise_gp_sd")
ROW_WEIGHT = "row_weight"  # Student-t noise: each row's weight in the fit (functions/noise.stan)
# heteroscedastic noise: g, the log noise sd GP before its mean over the settings is taken off, at the
# distinct settings of its inputs (log(sd / noise_sd) = g - mean g)
NOISE_LOCATIONS = "noise_locations"
NOISE_BAND = "90 %"  # the noise sd curve's band: 5 % to 95 % quantiles
PREDICTED = ("f_new", "delta_new", "zeta_new")
# biased measurement sources: each one's bias at the prediction points (functions/source_bias.stan)
BIAS_NEW = "bias_new"
NEW_OBSERVATION = "y_new"  # latent programs: a new observation from the likelihood
# per physical point: the GP part of delta (a draw, and its mean given the
# parameters), and E(y_i | y_-i) for held-out error
AT_OBSERVATIONS = ("delta_gp", "delta_gp_mean", "y_loo_mean")
# parameters of stancal's programs that the posterior group holds in another
# form (original units, or not at all: latent standard normals); any other
# parameter of a program goes into the posterior group as it is
_REEXPRESSED = {"theta_unit", "theta_low_unit", "noise_sd", "delta_sd", "delta_input_length_scale", "delta_relevance",
                "rho_free", "beta", "noise_weight", "noise_z", "noise_log_scale", "noise_length_scale",
                "inv_sqrt_phi", "delta_raw", "emulator_z", "theta_function_sd",
                "theta_function_length_scale", "theta_function_logit", "theta_function_raw",
                "bias_sd", "bias_length_scale"}


def add_prior(tree, prior_tree) -> None:
    """The prior run's groups into the fit's tree: its posterior as ``prior``,
    its replicated data as ``prior_predictive``, and the program's own
    parameters as ``prior_stan_parameters`` (what SBC simulates from)."""
    for group, source in (("prior", "posterior"), ("prior_predictive", "posterior_predictive"),
                          ("prior_stan_parameters", "stan_parameters")):
        tree[group] = prior_tree[source]


def build_datatree(sample: SampleOutput, data: CalibrationData,
                   new_points: pd.DataFrame, parameter_names: list[str],
                   options: ModelOptions) -> xr.DataTree:
    """The fit as an ArviZ DataTree: the posterior on the original scale, the
    posterior predictive, log likelihood, sampler statistics, predictions at
    ``new_points``, the values at the observations, the data, and the
    program's own parameters (for reruns)."""
    import arviz_base as ab

    d = sample.draws
    terms = mean_terms_of(data, options)
    sampled = {
        "posterior": _posterior(d, data, parameter_names, options, terms),
        "posterior_predictive": {"y": d["y_rep"]},
        "log_likelihood": {"y": d["log_lik"]},
        "sample_stats": sample.sample_stats,
        "predictions": {k: d[k] for k in (*PREDICTED, NEW_OBSERVATION) if k in d},
        "at_observations": {k: d[k] for k in AT_OBSERVATIONS if k in d},
    }
    if options.biased_sources:  # each biased source's bias curve at the prediction points
        sampled["predictions"][BIAS_NEW] = d[BIAS_NEW]
    if ROW_WEIGHT in d and d[ROW_WEIGHT].shape[-1]:  # Student-t noise
        sampled["at_observations"][ROW_WEIGHT] = d[ROW_WEIGHT]
    if options.functional:
        sampled["theta_functions"] = {"theta_function": d["theta_function_grid"]}
    locations = noise_locations(data, options)
    if locations is not None:
        sampled[NOISE_LOCATIONS] = {"log_scale": d["noise_log_scale"]}
    if "delta_basis_weights" in d and d["delta_basis_weights"].shape[-1]:  # the Hilbert-space discrepancy's
        sampled["discrepancy_basis"] = {"weights": d["delta_basis_weights"]}
    grid = functional_grid(data, options.functional_inputs)
    coords = _coords(data, new_points, options, terms, grid)
    dims = {**_DIMS, "noise_sd": ["source"]} if np.ndim(sampled["posterior"].get("noise_sd")) == 3 else _DIMS
    tree = ab.from_dict(sampled, dims=dims, coords=coords, pred_dims=dims, pred_coords=coords)
    if options.functional:  # the grid's input values, for plotting theta(x)
        tree["theta_functions"] = xr.DataTree(tree["theta_functions"].to_dataset().assign_coords(
            {c: ("grid_point", grid[c].to_numpy()) for c in grid.columns}))
    if locations is not None:  # each setting's input values, original units
        tree[NOISE_LOCATIONS] = xr.DataTree(tree[NOISE_LOCATIONS].to_dataset().assign_coords(
            {c: ("noise_location", data.scaling.low[c] + data.scaling.width[c] * locations.unit[:, j])
             for j, c in enumerate(locations.inputs)}))
    _add_data_groups(tree, data, new_points)
    tree["stan_parameters"] = xr.DataTree(ab.dict_to_dataset({k: d[k] for k in parameter_names}))
    if sample.inv_metric is not None:  # the adapted metric, for warm-started refits (stancal.fitting.warm_start)
        tree["adaptation"] = xr.DataTree(xr.Dataset({"inv_metric": (("chain", "unconstrained"), sample.inv_metric)}))
    return tree


def _posterior(d: Draws, data: CalibrationData, parameter_names: list[str], options: ModelOptions,
               terms) -> Draws:
    """The posterior group: the program's parameters in original units, and
    any parameter of a user's program as the program has it."""
    posterior: Draws = {out: d[stan] for stan, out in _REPORTED.items() if stan in d and d[stan].size}
    for name in _OPTIONAL_SCALARS:
        if name in posterior and posterior[name].ndim == 3 and posterior[name].shape[-1] <= 1:
            if posterior[name].shape[-1] == 0:
                del posterior[name]
            else:
                posterior[name] = posterior[name][..., 0]
    if options.has_discrepancy:
        widths = np.array([data.scaling.width[c] for c in data.discrepancy_inputs])
        posterior["delta_length_scale"] = d["delta_length_scale"] * widths
        covariates = len(data.discrepancy_inputs) - len(data.inputs)
        if covariates:  # per unit of each covariate: 0 switches it off
            posterior["delta_relevance"] = d["delta_relevance"] / widths[len(data.inputs):]
    if options.functional:
        widths = np.array([data.scaling.width[c] for c in options.functional_inputs])
        posterior["theta_function_sd"] = d["theta_function_sd"]
        posterior["theta_function_length_scale"] = d["theta_function_length_scale"] * widths
    if "noise_length_scale" in d and d["noise_length_scale"].shape[-1]:  # heteroscedastic: original units
        inputs = noise_input_names(options, data)
        posterior["noise_length_scale"] = d["noise_length_scale"] * np.array([data.scaling.width[c] for c in inputs])
    if options.biased_sources:  # each biased source's bias GP, original units
        posterior["bias_sd"] = d["bias_sd"] * data.scaling.y_scale
        posterior["bias_length_scale"] = d["bias_length_scale"] * np.array([data.scaling.width[c]
                                                                            for c in data.inputs])
    if not options.estimate_rho:
        posterior.pop("rho", None)
    for name in EMULATOR_HYPERPARAMETERS:
        if name in d:
            posterior[name] = d[name]
    if terms is not None:  # coefficients per raw term, in the discrepancy's units
        posterior["beta"] = d["beta"] * data.discrepancy_units / terms.scale
    for name in parameter_names:  # a parameter of the user's own program, as the program has it
        if name not in _REEXPRESSED and name not in posterior and d[name].size:
            posterior[name] = d[name]
    return posterior


_DIMS = {
    "theta": ["theta_name"], "theta_low": ["theta_low_name"],
    "delta_length_scale": ["delta_input"], "delta_relevance": ["delta_covariate"],
    "emulator_length_scale": ["emulator_input"], "y": ["obs"], "beta": ["mean_term"],
    **{k: ["obs"] for k in AT_OBSERVATIONS},
    **{k: ["new_point"] for k in (*PREDICTED, NEW_OBSERVATION)},
    "theta_function_sd": ["functional_theta"],
    "theta_function_length_scale": ["functional_theta", "functional_input"],
    "theta_function": ["grid_point", "functional_theta"],
    "weights": ["basis_function"], ROW_WEIGHT: ["obs"],
    "noise_length_scale": ["noise_input"], "log_scale": ["noise_location"],
    "bias_sd": ["biased_source"], "bias_length_scale": ["biased_source", "bias_input"],
    BIAS_NEW: ["biased_source", "new_point"],
}


def _coords(data: CalibrationData, new_points: pd.DataFrame, options: ModelOptions, terms,
            grid: pd.DataFrame) -> dict:
    return {
        "theta_name": data.theta_names, "theta_low_name": data.theta_low_names, "delta_input": data.discrepancy_inputs,
        "delta_covariate": data.discrepancy_inputs[len(data.inputs):],
        "emulator_input": [*data.inputs, *data.theta_names],
        "obs": np.arange(len(data.physical)), "new_point": np.arange(len(new_points)),
        "mean_term": terms.names if terms else [],
        "functional_theta": list(options.functional), "functional_input": list(options.functional_inputs),
        "grid_point": np.arange(len(grid)), "source": list(data.noise.sources),
        "noise_input": noise_input_names(options, data),
        "biased_source": list(options.biased_sources), "bias_input": data.inputs,
    }


def _add_data_groups(tree: xr.DataTree, data: CalibrationData, new_points: pd.DataFrame) -> None:
    """observed_data, constant_data (inputs, censoring, trials) and the prediction points."""
    obs = {"obs": np.arange(len(data.physical))}
    tree["observed_data"] = xr.DataTree(xr.Dataset(
        {"y": ("obs", data.physical[data.output].to_numpy())}, coords=obs))
    observations = data.observations
    tree["constant_data"] = xr.DataTree(xr.Dataset(
        {**{c: ("obs", data.physical[c].to_numpy()) for c in data.discrepancy_inputs},
         **({"censoring": ("obs", observations.censoring), "lower": ("obs", observations.lower),
             "upper": ("obs", observations.upper)} if observations.any_censored else {}),
         **({"trials": ("obs", observations.trials)} if data.observation_columns["trials"] else {})},
        coords=obs))
    tree["predictions_constant_data"] = xr.DataTree(xr.Dataset(
        {c: ("new_point", new_points[c].to_numpy()) for c in new_points},
        coords={"new_point": np.arange(len(new_points))}))


def interval_table(values: np.ndarray, prefix: str) -> dict[str, np.ndarray]:
    """values: (samples, points) -> mean and quantiles per point."""
    return {f"{prefix}_{k}": v for k, v in band(values).items()}


@dataclass
class CalibrationResult:
    """Posterior of one calibration. ``idata`` is the ArviZ DataTree."""

    idata: xr.DataTree
    data: CalibrationData
    method: str
    backend: str
    options: ModelOptions
    program: FlatProgram
    timing: dict[str, float]
    # None until the sampler has been checked (a result is saved before that)
    diagnostics: Diagnostics | None = None
    modes: list[Mode] = field(default_factory=list)
    emulator: dict[str, Any] = field(default_factory=dict)  # stage-1 results of modular
    # L2 calibration (l2.py): theta is the projection of each zeta draw; empty otherwise
    l2: dict[str, Any] = field(default_factory=dict)
    # the registry row that ran: it travels with the result (to Dask workers, say), so a
    # program registered in one process predicts in another; None for a result loaded from disk
    registry_row: Program | None = None
    # a theta confounded with a model term, found before sampling (stancal.fitting.confounding):
    # each finding as JSON, with what was done (the constant dropped) or said
    confounding: list[dict[str, Any]] = field(default_factory=list)

    @property
    def row(self) -> Program:
        """The registry row of the program that made this result."""
        return self.registry_row or program(self.method)

    @property
    def estimator(self) -> str:
        """What theta is: 'l2' (projection of the fit's zeta) or the fit's method."""
        return "l2" if self.l2 else self.method

    # ---- summaries -------------------------------------------------------
    def summary(self) -> pd.DataFrame:
        """theta and hyperparameters on the original scale. With several theta
        modes, one block of rows per mode (column ``mode``, 1 = the heaviest,
        or the highest density when the masses are unknown; column ``weight``,
        its share of the posterior mass)."""
        return summary_by_mode(self.idata["posterior"].to_dataset(), self.modes)

    def theta_summary(self) -> dict[str, dict[str, float]]:
        """theta's posterior summary. With several modes whose masses are
        known, that of their mixture, each mode weighted by its mass (R-hat
        is the worst within a mode, ESS the smallest)."""
        return theta_summary(self.idata["posterior"].to_dataset(), self.modes, self.data.theta_names)

    def outliers(self) -> pd.DataFrame:
        """The rows a Student-t fit discounts: posterior mean weight below
        stancal.problem.noise.OUTLIER_WEIGHT (West 1984), lowest first, with
        their inputs and output; empty for normal noise."""
        group = self.idata["at_observations"]
        if ROW_WEIGHT not in group:
            return pd.DataFrame(columns=["row", "weight"])
        table = outlier_rows(np.asarray(group[ROW_WEIGHT]))
        physical = self.data.physical.reset_index(drop=True)
        return table.join(physical[[*self.data.inputs, self.data.output]], on="row")

    def noise_summary(self) -> dict[str, Any]:
        """The noise model: its name, each source's rows, the known-sd column,
        (Student-t) the outliers and (heteroscedastic) the replicates and the
        noise sd curve, for summary.json and the report."""
        noise = self.data.noise
        out = {"model": self.options.noise, "known_sd_column": noise.noise_sd_column,
               "source_column": noise.source_column,
               "rows_per_source": dict(zip(noise.sources, noise.rows_per_source.tolist(), strict=True)),
               "outlier_rule": f"posterior mean Student-t weight < {OUTLIER_WEIGHT}",
               "outliers": json.loads(self.outliers().to_json(orient="records"))}
        if self.options.biased_sources:  # stancal.problem.source_bias
            out.update(biased_sources=list(self.options.biased_sources), bias_band=NOISE_BAND,
                       reference_sources=[s for s in noise.sources if s not in self.options.biased_sources])
        if NOISE_LOCATIONS in self.idata.children:
            curve = self.noise_curve()
            out.update(noise_inputs=noise_input_names(self.options, self.data), band=NOISE_BAND,
                       replicates=replicate_counts(self.data.physical[self.data.discrepancy_inputs].to_numpy()),
                       sd_curve={c: curve[c].tolist() for c in curve.columns})
        return out

    def source_biases(self, bias_new: np.ndarray, points: int) -> dict[str, np.ndarray]:
        """Each biased source's bias at ``points`` new points, (samples, points),
        by source name, from the programs' ``bias_new`` draws (functions/source_bias.stan)."""
        values = np.asarray(bias_new).reshape(-1, len(self.options.biased_sources), points)
        return {name: values[:, b] for b, name in enumerate(self.options.biased_sources)}

    def reading_bias(self, points: pd.DataFrame, biases: dict[str, np.ndarray]) -> np.ndarray | float:
        """The bias of each point's own source (0 for a reference source), where
        the points name their source: a new reading by that instrument; without
        a source column (or biased sources), a reading free of any instrument's bias."""
        source, _ = self.data.noise.at(points)
        if not biases or source is None:
            return 0.0
        names = np.asarray(self.data.noise.sources)[source]
        out = np.zeros_like(next(iter(biases.values())))
        for name, values in biases.items():
            out[:, names == name] = values[:, names == name]
        return out

    def noise_sd_at(self, points: pd.DataFrame, rng: np.random.Generator | None = None,
                    step: int = 1, locations: NoiseLocations | None = None) -> np.ndarray:
        """Heteroscedastic noise: the noise sd (output units) at ``points``
        per posterior draw (every ``step``-th of each chain), (draws, points):
        noise_sd (the sd's geometric mean over the settings) times exp(g - mean
        of g at the settings), g the log sd GP's conditional at the points
        (stancal.numerics.noise_gp: its mean, or a draw with ``rng``);
        ``locations``: the fit's settings, where the caller has them already."""
        locations = locations or noise_locations(self.data, self.options)
        assert locations is not None, "noise_sd_at: the fit's noise is not heteroscedastic"
        posterior = self.idata["posterior"].isel(draw=slice(None, None, step))
        values = np.asarray(self.idata[NOISE_LOCATIONS]["log_scale"])[:, ::step]
        widths = np.array([self.data.scaling.width[c] for c in locations.inputs])
        log_scale = log_scale_at(self.data.scaling.to_unit(points, locations.inputs), locations.unit,
                                 values.reshape(-1, values.shape[-1]),
                                 np.asarray(posterior["noise_gp_sd"]).ravel(),
                                 np.asarray(posterior["noise_length_scale"]).reshape(-1, len(widths)) / widths,
                                 rng)
        # noise_sd is the sd's geometric mean over the settings: g centred there (functions/noise.stan)
        centre = values.reshape(-1, values.shape[-1]).mean(axis=1, keepdims=True)
        return np.asarray(posterior["noise_sd"]).reshape(-1, 1) * np.exp(log_scale - centre)

    def noise_curve(self, size: int = 60) -> pd.DataFrame:
        """Heteroscedastic noise: the noise sd's posterior mean and 90 % band
        (output units; the estimated part, without any known sd) over its one
        input (``size`` points across the physical data's range), or at the
        distinct settings of its several inputs; a draw of the GP between them."""
        locations = noise_locations(self.data, self.options)
        assert locations is not None, "noise_curve: the fit's noise is not heteroscedastic"
        physical = self.data.physical
        if len(locations.inputs) == 1:
            column = locations.inputs[0]
            points = pd.DataFrame({column: np.linspace(physical[column].min(), physical[column].max(), size)})
        else:
            points = physical[list(locations.inputs)].drop_duplicates().sort_values(list(locations.inputs))
        sd = self.noise_sd_at(points.reset_index(drop=True), np.random.default_rng(0), locations=locations)
        summary = band(sd)
        return points.reset_index(drop=True).assign(**{k: summary[k] for k in ("mean", "q05", "q50", "q95")})

    def theta_draws(self) -> pd.DataFrame:
        theta = self.idata["posterior"]["theta"]
        flat = np.asarray(theta).reshape(-1, theta.shape[-1])
        return pd.DataFrame(flat, columns=self.data.theta_names)

    # ---- prediction ------------------------------------------------------
    def predict(self, new_points: pd.DataFrame | None = None, *, backend: str | None = None,
                seed: int = 1, max_draws: int | None = None) -> pd.DataFrame:
        """zeta (the real process), f(x, theta) and delta at ``new_points``
        (columns: simulator inputs and covariates), with 5/50/95 % quantiles,
        plus ``y`` with measurement noise. Without ``new_points``, the points
        stored with the fit. See stancal.fitting.predict."""
        # imported here: rerunning Stan at new points is fitting's job, and a result holds data only
        from stancal.fitting.predict import predict

        return predict(self, new_points, backend=backend, seed=seed, max_draws=max_draws)

    # ---- persistence -----------------------------------------------------
    def _metadata(self) -> dict[str, Any]:
        return {
            "method": self.method, "backend": self.backend,
            "options": asdict(self.options),
            "program": {"code": self.program.code, "origin": self.program.origin},
            "data": self.data.to_dict(),
            "diagnostics": self.diagnostics and self.diagnostics.to_dict(), "modes": [m.__dict__ for m in self.modes],
            "timing": self.timing, "emulator": self.emulator, "l2": self.l2, "confounding": self.confounding,
        }

    def save(self, path: str | Path) -> Path:
        """Write the DataTree and everything needed to reload it as netCDF."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        tree = self.idata.copy()
        tree.attrs["stancal"] = json.dumps(self._metadata())
        tree.to_netcdf(path)
        return path

    @classmethod
    def load(cls, path: str | Path) -> CalibrationResult:
        tree = xr.open_datatree(path).load()
        meta = json.loads(tree.attrs.pop("stancal"))
        return cls(
            idata=tree, data=CalibrationData.from_dict(meta["data"]), method=meta["method"],
            backend=meta["backend"], options=ModelOptions(**meta["options"]),
            program=FlatProgram(meta["program"]["code"],
                                tuple(tuple(o) for o in meta["program"]["origin"])),
            diagnostics=meta["diagnostics"] and Diagnostics(**meta["diagnostics"]),
            modes=[Mode(**m) for m in meta["modes"]], timing=meta["timing"],
            emulator=meta["emulator"], l2=meta.get("l2", {}), confounding=meta.get("confounding", []),
        )

    def to_summary_json(self) -> dict[str, Any]:
        d = self.diagnostics
        return {
            "method": self.estimator,
            "backend": self.backend,
            "options": asdict(self.options),
            "theta": self.theta_summary(),
            **({"theta_low": theta_summary(self.idata["posterior"].to_dataset(), self.modes, self.data.theta_low_names,
                                           variable="theta_low")} if self.data.theta_low_names else {}),
            "modes": [m.to_dict() for m in self.modes],
            "parameters": json.loads(self.summary().reset_index().to_json(orient="records")),
            "diagnostics": d.summary(),
            "timing": self.timing,
            "emulator": {k: v for k, v in self.emulator.items() if k != "hyperparameters"},
            **({"l2": self.l2} if self.l2 else {}),
            **({"confounding": self.confounding} if self.confounding else {}),
            "likelihood": self.data.observations.likelihood.name.lower(),
            **({"noise": self.noise_summary()} if describes_noise(self.options, self.data) else {}),
            **({"censoring": self.data.observations.counts_by_kind()}
               if self.data.observations.any_censored else {}),
            **({"theta_functions": self.theta_functions()} if self.options.functional else {}),
        }

    def theta_functions(self) -> dict[str, dict]:
        """Each functional theta on its grid: mean and 90 % band (original units)."""
        group = self.idata["theta_functions"].to_dataset()
        curves = np.asarray(group["theta_function"])
        grid = pd.DataFrame({c: np.asarray(group[c]) for c in self.options.functional_inputs})
        return theta_function_summary(curves.reshape(-1, *curves.shape[2:]), grid,
                                      list(self.options.functional))
