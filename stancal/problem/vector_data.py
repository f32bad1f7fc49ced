"""A validated calibration problem whose simulator returns a vector (a
curve, a field, a set of features) and whose experiments each measure part
of it, at their own output indices (review section 8.1.1; Higdon et al.
2008). Both tables are long: one row per measured or simulated value."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
import pandas as pd

from stancal.problem.categories import covariate_columns, covariate_levels, one_hot
from stancal.problem.data import (
    Parameter,
    Scaling,
    bounds_of,
    numeric_columns,
    parameters_from_bounds,
    require_columns,
    require_runs_within_bounds,
    simulators_runs,
    warn_outside_runs,
)
from stancal.problem.fidelity_rho import check_low_fidelity_rho
from stancal.problem.output_basis import DEFAULT_VARIANCE_SHARE, OutputBasis
from stancal.problem.validation import DataError, described
from stancal.problem.validation import row_labels as _rows


def _constant_within(table: pd.DataFrame, group: str, columns: Sequence[str], what: str, unit: str) -> pd.DataFrame:
    """One row per group with the columns' values (numbers or text), which
    must not vary within a group (an error names the group and the column)."""
    grouped = table.groupby(group, sort=False)
    for column in columns:
        distinct = grouped[column].nunique()
        varying = distinct[distinct > 1]
        if len(varying):
            name = varying.index[0]
            values = table.loc[table[group] == name, column].unique()[:5].tolist()
            raise DataError(f"{what}: column '{column}' varies within {unit} '{name}' ({values}); "
                            f"it must be constant within each {unit} ({len(varying)} {unit}s vary)")
    return grouped[list(columns)].first()


class VectorCalibrationData:
    """Experiments measuring a vector output, simulator runs on one grid of
    output indices, and the calibration parameters.

    Parameters
    ----------
    physical : long DataFrame, one row per measured value: the experiment
        column, the simulator inputs and covariates (constant within an
        experiment), the output index column(s) and the output.
    experiment : the column naming each row's experiment.
    inputs : simulator input columns, in the simulator's order.
    output : the output column (same name in ``runs``).
    output_index : where a value sits along the output: one column (time,
        position, feature number) or several (a field).
    theta : calibration parameters shared by all experiments, name -> (lower, upper).
    theta_per_experiment : parameters with one value per experiment (a shot's
        impact velocity), name -> (lower, upper).
    runs : long DataFrame, one row per simulated value: the run column, the
        inputs, every theta, the output index column(s) and the output. All
        runs share one grid of output indices; or a list of several
        simulators' runs, cheapest first, the calibrated simulator's last (as
        ``low_fidelity_runs`` and ``runs``).
    run : the column naming each row's run.
    noise_sd : optional column of each measured value's known sd.
    covariates : physical columns the discrepancy may depend on (constant
        within an experiment); text columns are categorical and enter the
        discrepancy one-hot, as for a scalar output (stancal.problem.categories).
    variance_share, components : the runs' reduced basis (stancal.problem.output_basis).
    levels : categories of categorical covariates, when they must not be
        taken from ``physical`` (a subset that lacks a level).
    low_fidelity_runs : long runs of cheaper simulators of the same process
        (a DataFrame for one, or a list, cheapest first), with the columns of ``runs`` (each level on one grid
        of its own, within the runs' range): each component weight's
        emulator learns from them too (Kennedy & O'Hagan 2000;
        docs/multifidelity.md). The basis is ``runs``'s; these are projected
        on it.
    low_fidelity_rho : the scale between levels: "constant" only for a vector output.
    """

    def __init__(
        self,
        physical: pd.DataFrame,
        experiment: str,
        inputs: Sequence[str],
        output: str,
        output_index: str | Sequence[str],
        theta: Mapping[str, tuple[float, float]],
        theta_per_experiment: Mapping[str, tuple[float, float]] | None = None,
        runs: pd.DataFrame | Sequence[pd.DataFrame] | None = None,
        run: str | None = None,
        noise_sd: str | None = None,
        covariates: Sequence[str] = (),
        variance_share: float = DEFAULT_VARIANCE_SHARE,
        components: int | None = None,
        levels: Mapping[str, Sequence[str]] | None = None,
        low_fidelity_runs: pd.DataFrame | Sequence[pd.DataFrame] = (),
        low_fidelity_rho: str = "constant",
    ) -> None:
        low_fidelity_runs, runs = simulators_runs(runs, low_fidelity_runs)  # the scalar path's forms
        self.experiment, self.run, self.output, self.noise_sd = experiment, run, output, noise_sd
        self.inputs, self.covariates = list(inputs), list(covariates)
        self.output_index = [output_index] if isinstance(output_index, str) else list(output_index)
        self.parameters = parameters_from_bounds(theta)
        self.per_experiment = parameters_from_bounds(theta_per_experiment or {}, "theta_per_experiment",
                                                     required=False)
        self._check_names()
        require_columns(physical, self.covariates, described("physical data", physical))
        self.levels = covariate_levels(physical, self.covariates, levels or {}, described("physical data", physical))
        self.physical = self._check_physical(physical)
        self.source = physical.loc[self.physical.index].copy()  # every column, for formulas
        self.source[experiment] = self.physical[experiment]
        self.experiments = self._experiments(described("physical data", physical))
        self.runs = None
        self.basis = None
        self._basis_options = {"variance_share": variance_share, "components": components}
        if runs is not None:
            if run is None:
                raise DataError("simulator runs: name the column that identifies each run (run = ...)")
            self.runs, self.run_settings, self.run_outputs, grid = self._check_runs(runs)
            self.basis = OutputBasis.from_runs(grid, self.run_outputs, variance_share, components)
            self._check_indices_on_grid()
        self.low_fidelity_runs, self.low_fidelity_settings, self.low_fidelity_weights = self._check_low_fidelity(
            low_fidelity_runs)
        # which forms a program takes is the registry's (stancal.fitting.plan), as for scalar outputs
        self.low_fidelity_rho = check_low_fidelity_rho(low_fidelity_rho, len(self.low_fidelity_runs), False)
        self.scaling = self._scaling()

    @property
    def theta_names(self) -> list[str]:
        return [p.name for p in self.parameters]

    @property
    def fidelities(self) -> int:
        """How many simulators of the process have runs: 1, or more with low-fidelity runs."""
        return 1 + len(self.low_fidelity_runs)

    @property
    def theta_low_names(self) -> list[str]:
        """The cheapest simulator's own theta_l: none, a vector output's levels share theta."""
        return []

    def run_count(self) -> int:
        """Runs of every fidelity (a run is one curve, many rows)."""
        return sum(len(s) for s in [*self.low_fidelity_settings, *([] if self.runs is None else [self.run_settings])])

    def _check_low_fidelity(self, given: list[pd.DataFrame]
                            ) -> tuple[list[pd.DataFrame], list[pd.DataFrame], list[np.ndarray]]:
        """Each cheaper level's runs checked as the runs are, their settings
        (one row per run) and their weights on the calibrated simulator's
        basis (OutputBasis.project), cheapest first."""
        if not given:
            return [], [], []
        if self.basis is None:
            raise DataError("low-fidelity runs need the runs of the simulator being calibrated (runs = ...): "
                            "the basis and the emulator's top level come from them")
        checked = [self._check_runs(runs, "low-fidelity runs", warn=False) for runs in given]
        return ([table for table, _, _, _ in checked], [settings for _, settings, _, _ in checked],
                [self.basis.project(grid, outputs) for _, _, outputs, grid in checked])

    @property
    def has_runs(self) -> bool:
        """Simulator runs were given (and reduced to a basis)."""
        return self.basis is not None

    @property
    def all_parameters(self) -> list[Parameter]:
        """The shared theta, then the per-experiment ones (each of those
        once per experiment in a fit)."""
        return [*self.parameters, *self.per_experiment]

    @property
    def discrepancy_variables(self) -> dict[str, list[str]]:
        """The discrepancy GP's variables -> their columns: simulator inputs,
        output index, covariates (one column per level for a categorical
        one), in the Stan programs' x_delta order."""
        return {c: [c] for c in [*self.inputs, *self.output_index]} | covariate_columns(self.covariates, self.levels)

    @property
    def discrepancy_inputs(self) -> list[str]:
        return [column for columns in self.discrepancy_variables.values() for column in columns]

    @property
    def covariate_columns(self) -> list[str]:
        """The covariates' discrepancy columns (the Stan programs' z, D_cov of them)."""
        return [column for columns in covariate_columns(self.covariates, self.levels).values() for column in columns]

    def with_one_hot(self, rows: pd.DataFrame, what: str = "prediction rows") -> pd.DataFrame:
        """Rows (physical, or where predictions are drawn) with the one-hot
        columns of the categorical covariates added."""
        if not self.levels:
            return rows
        coded = one_hot(rows, self.levels, what)
        return pd.concat([rows.drop(columns=list(coded.columns), errors="ignore"), coded], axis=1)

    @property
    def discrepancy_scale(self) -> str:
        return "output units"

    def heldout_log_density(self, rows: np.ndarray, zeta: np.ndarray, posterior,
                            estimated_sd: np.ndarray | None = None) -> np.ndarray:
        """log p(y_row | zeta, noise) per draw (draws, rows) for held-out
        values: their known sd, or the fit's noise sd (one, or their
        experiment's). ``estimated_sd``: as CalibrationData's; a vector
        output has no heteroscedastic noise, so it is always None here."""
        if estimated_sd is not None:
            raise ValueError("a vector output's noise has no sd curve (heteroscedastic noise is for scalar outputs)")
        y = self.physical[self.output].to_numpy()[rows]
        if self.noise_sd:
            sd = np.broadcast_to(self.physical[self.noise_sd].to_numpy()[rows], zeta.shape)
        elif posterior["noise_sd"].ndim > 2:
            experiments = self.physical[self.experiment].to_numpy()[rows]
            sd = np.column_stack([np.asarray(posterior["noise_sd"].sel(experiment=e)).ravel() for e in experiments])
        else:
            sd = np.broadcast_to(np.asarray(posterior["noise_sd"]).reshape(-1, 1), zeta.shape)
        return -0.5 * np.log(2 * np.pi) - np.log(sd) - 0.5 * ((y - zeta) / sd) ** 2

    def subset(self, rows: Sequence[int]) -> VectorCalibrationData:
        """The same problem on some measured values (positions); the runs,
        and so the basis, are unchanged."""
        return self._rebuilt(self.source.iloc[list(rows)], self.runs)

    def with_output(self, y: np.ndarray) -> VectorCalibrationData:
        """The same problem with other measured values (simulated ones, one per
        row of ``physical`` in its order) and this problem's scaling kept, as
        CalibrationData.with_output: a fit of simulated data must standardise
        as the simulation did (the runs, and so the basis, are unchanged)."""
        y = np.asarray(y, float)
        if y.shape != (len(self.physical),):
            raise ValueError(f"with_output: {len(self.physical)} values needed (one per measured value); "
                             f"got shape {y.shape}")
        source = self.source.copy()
        source[self.output] = y
        other = self._rebuilt(source, self.runs)
        other.scaling = self.scaling
        return other

    def with_runs(self, runs: pd.DataFrame) -> VectorCalibrationData:
        """The same problem with other simulator runs (a long table, as ``runs``),
        its basis made again from them."""
        return self._rebuilt(self.source, runs)

    def _rebuilt(self, source: pd.DataFrame, runs: pd.DataFrame | None) -> VectorCalibrationData:
        """This problem rebuilt (and checked) on other measured values or runs; same categories and basis options."""
        return VectorCalibrationData(
            source, self.experiment, self.inputs, self.output, self.output_index, bounds_of(self.parameters),
            bounds_of(self.per_experiment), runs, self.run, self.noise_sd, self.covariates,
            **self._basis_options, levels=self.levels,
            low_fidelity_runs=self.low_fidelity_runs if runs is not None else (),
            low_fidelity_rho=self.low_fidelity_rho if runs is not None else "constant")

    def variant(self, inputs: Sequence[str],
                extra_theta: Mapping[str, tuple[float, float]]) -> VectorCalibrationData:
        """The problem as a simulator variant sees it: its own inputs, the
        shared theta then its extra ones (the per-experiment theta after
        them), no runs; the discrepancy keeps every input and covariate."""
        return VectorCalibrationData(
            self.source, self.experiment, inputs, self.output, self.output_index,
            bounds_of(self.parameters) | dict(extra_theta), bounds_of(self.per_experiment),
            noise_sd=self.noise_sd, covariates=[v for v in [*self.inputs, *self.covariates] if v not in inputs],
            levels=self.levels)

    def _scaling(self) -> Scaling:
        """Inputs and covariates to [0, 1] over the experiments' and runs'
        range, theta over its bounds, the output index over the runs' grid and
        the measured indices. The output is standardised by its mean and sd
        over the measured values (the Stan simulator's program); the runs'
        program standardises by the basis (its mean curve and scale)."""
        low, width = {}, {}
        ranges = {c: self.experiments[c].to_numpy() for c in [*self.inputs, *self.covariate_columns]}
        ranges.update({c: self.physical[c].to_numpy() for c in self.output_index})
        if self.basis is not None:
            for c in self.inputs:
                ranges[c] = np.concatenate([ranges[c], *(s[c].to_numpy() for s in
                                                         [self.run_settings, *self.low_fidelity_settings])])
            for d, c in enumerate(self.output_index):
                ranges[c] = np.concatenate([ranges[c], self.basis.grid[:, d]])
        for column, values in ranges.items():
            low[column], width[column] = float(values.min()), float(np.ptp(values)) or 1.0
        for p in self.all_parameters:
            low[p.name], width[p.name] = p.lower, p.upper - p.lower
        y = self.physical[self.output].to_numpy()
        return Scaling(low, width, float(y.mean()), float(y.std()) or 1.0)

    def _check_names(self) -> None:
        named = [self.experiment, *self.inputs, *self.covariates, *self.output_index, self.output,
                 *([self.noise_sd] if self.noise_sd else [])]
        repeated = sorted({c for c in named if named.count(c) > 1})
        if repeated:
            raise DataError(f"column(s) {repeated} named more than once among experiment, inputs, covariates, "
                            f"output index, output and noise sd")
        thetas = [p.name for p in self.all_parameters]
        clash = sorted(set(thetas) & set(named)) or sorted({t for t in thetas if thetas.count(t) > 1})
        if clash:
            raise DataError(f"theta name(s) {clash} clash with a column or with each other")

    def _check_physical(self, physical: pd.DataFrame) -> pd.DataFrame:
        what = described("physical data", physical)
        require_columns(physical, [self.experiment], what)
        numeric = [c for c in self.covariates if c not in self.levels]
        values = [*self.inputs, *numeric, *self.output_index, self.output, *([self.noise_sd] if self.noise_sd else [])]
        table = pd.concat([numeric_columns(physical, values, what), one_hot(physical, self.levels, what)], axis=1)
        empty = physical[self.experiment].isna().to_numpy()
        if empty.any():
            raise DataError(f"{what}: column '{self.experiment}' is empty in {_rows(empty, physical.index)}")
        table.insert(0, self.experiment, physical[self.experiment].astype(str))
        if self.noise_sd:
            bad = table[self.noise_sd].to_numpy() <= 0
            if bad.any():
                raise DataError(f"{what}: column '{self.noise_sd}' (known noise sd) must be positive; "
                                f"{_rows(bad, table.index)}")
        if len(table) < 3:
            raise DataError(f"{what}: {len(table)} rows; calibration needs at least 3")
        return table

    def _experiments(self, what: str) -> pd.DataFrame:
        """One row per experiment with its inputs and covariate columns, which
        must not vary within it (a categorical covariate checked by its text,
        so that the error names its column and levels)."""
        checked = self.physical[[self.experiment, *self.inputs, *(c for c in self.covariates if c not in self.levels)]]
        checked = checked.assign(**{c: self.source[c].astype(str) for c in self.levels})
        _constant_within(checked, self.experiment, [*self.inputs, *self.covariates], what, "experiment")
        return self.physical.groupby(self.experiment, sort=False)[[*self.inputs, *self.covariate_columns]].first()

    def _check_runs(self, runs: pd.DataFrame, label: str = "simulator runs",
                    warn: bool = True) -> tuple[pd.DataFrame, pd.DataFrame, np.ndarray, np.ndarray]:
        """The runs' table, one row of settings per run (inputs, every theta), their
        outputs (runs, K) on the shared grid (K, index columns); ``warn``: when
        the experiments lie outside the runs' inputs (the calibrated simulator's runs)."""
        what = described(label, runs)
        require_columns(runs, [self.run], what)
        every_theta = [p.name for p in self.all_parameters]
        table = numeric_columns(runs, [*self.inputs, *every_theta, *self.output_index, self.output], what)
        table.insert(0, self.run, runs[self.run].astype(str))
        require_runs_within_bounds(table, self.all_parameters)
        if warn:
            warn_outside_runs(self.physical, table, self.inputs)
        settings = _constant_within(table, self.run, [*self.inputs, *every_theta], what, "run")
        ordered = table.sort_values([self.run, *self.output_index], kind="stable")
        grids = {name: group[self.output_index].to_numpy() for name, group in ordered.groupby(self.run, sort=False)}
        first_name, grid = next(iter(grids.items()))
        for name, other in grids.items():
            if other.shape != grid.shape or not np.allclose(other, grid):
                raise DataError(f"{what}: run '{name}' is on a grid of {len(other)} output indices that differs "
                                f"from run '{first_name}''s ({len(grid)}); every run must return the same "
                                f"output indices ({', '.join(self.output_index)})")
            if len(np.unique(other, axis=0)) < len(other):
                raise DataError(f"{what}: run '{name}' repeats an output index")
        outputs = np.vstack([ordered.loc[ordered[self.run] == name, self.output].to_numpy() for name in settings.index])
        return table, settings, outputs, grid

    def _check_indices_on_grid(self) -> None:
        """Experiments' indices must lie within the runs' grid (no extrapolation of the basis)."""
        grid = self.basis.grid
        for d, column in enumerate(self.output_index):
            lo, hi = grid[:, d].min(), grid[:, d].max()
            values = self.physical[column].to_numpy()
            outside = (values < lo) | (values > hi)
            if outside.any():
                experiments = sorted(self.physical.loc[outside, self.experiment].unique())[:5]
                raise DataError(f"{described('physical data', self.physical)}: output index '{column}' lies "
                                f"outside the runs' range [{lo:g}, {hi:g}] in {_rows(outside, self.physical.index)} "
                                f"(experiments {experiments}); the output basis cannot extrapolate")
        if len(self.output_index) > 1:  # inside each range but outside the grid's hull
            try:
                self.basis.at(self.physical[self.output_index].to_numpy())
            except DataError as err:
                raise DataError(f"{described('physical data', self.physical)}: {err}") from None

