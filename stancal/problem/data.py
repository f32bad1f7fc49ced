"""One validated container for a calibration problem: physical data,
optional simulator runs, and the calibration parameters with their bounds."""

from __future__ import annotations

import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd

from stancal.problem.categories import covariate_columns, covariate_levels, one_hot
from stancal.problem.fidelity_rho import check_low_fidelity_rho, check_rho_identified
from stancal.problem.low_fidelity_theta import check_low_fidelity_theta
from stancal.problem.noise import MeasurementNoise, read_measurement_noise, row_noise_sd, with_known_sd
from stancal.problem.observations import LINKS, read_observations
from stancal.problem.validation import DataError, described, numeric_values, require_whole, source_file
from stancal.problem.validation import row_labels as _rows


class InputRangeWarning(UserWarning):
    """Physical inputs outside the range covered by the simulator runs."""


@dataclass(frozen=True)
class Parameter:
    """A calibration parameter; its bounds are the support of a uniform prior."""

    name: str
    lower: float
    upper: float


def require_columns(frame: pd.DataFrame, columns: Sequence[str], what: str) -> None:
    if frame.columns.duplicated().any():
        dup = sorted(set(frame.columns[frame.columns.duplicated()]))
        raise DataError(f"{what}: duplicate column(s) {dup}")
    missing = [c for c in columns if c not in frame.columns]
    if missing:
        raise DataError(
            f"{what}: missing column(s) {missing}; available: {list(frame.columns)}"
        )


def numeric_columns(frame: pd.DataFrame, columns: Sequence[str], what: str) -> pd.DataFrame:
    """The named columns as floats, or a DataError naming the column and rows."""
    require_columns(frame, columns, what)
    out = {}
    for column in columns:
        values = numeric_values(frame, column, what)
        bad = ~np.isfinite(values)
        if bad.any():
            raise DataError(
                f"{what}: column '{column}' has NaN or inf in {_rows(bad, frame.index)}"
            )
        out[column] = values
    return pd.DataFrame(out, index=frame.index)


def parameters_from_bounds(theta: Mapping[str, tuple[float, float]], what: str = "theta",
                           required: bool = True) -> list[Parameter]:
    """Parameters from name -> (lower, upper), each checked (the error names it)."""
    if required and not theta:
        raise DataError(f"{what}: give at least one calibration parameter with bounds")
    out = []
    for name, bounds in theta.items():
        try:
            lower, upper = (float(b) for b in bounds)
        except (TypeError, ValueError):
            raise DataError(f"{what} '{name}': bounds must be two numbers [lower, upper]; got {bounds!r}") from None
        if not (np.isfinite(lower) and np.isfinite(upper) and lower < upper):
            raise DataError(f"{what} '{name}': bounds must be finite with lower < upper; got [{lower}, {upper}]")
        out.append(Parameter(name, lower, upper))
    return out


def bounds_of(parameters: Sequence[Parameter]) -> dict[str, tuple[float, float]]:
    """name -> (lower, upper): the form the data containers take theta in."""
    return {p.name: (p.lower, p.upper) for p in parameters}


def require_runs_within_bounds(runs: pd.DataFrame, parameters: Sequence[Parameter]) -> None:
    """Each run's theta inside its prior box (the error names column and rows)."""
    for p in parameters:
        values = runs[p.name].to_numpy()
        bad = (values < p.lower) | (values > p.upper)
        if bad.any():
            raise DataError(f"{described('simulator runs', runs)}: column '{p.name}' lies outside its bounds "
                            f"[{p.lower}, {p.upper}] in {_rows(bad, runs.index)}")


def simulators_runs(runs: pd.DataFrame | Sequence[pd.DataFrame] | None,
                    low_fidelity_runs: pd.DataFrame | Sequence[pd.DataFrame]
                    ) -> tuple[list[pd.DataFrame], pd.DataFrame | None]:
    """The cheaper simulators' runs (cheapest first) and the calibrated
    simulator's, from ``runs`` (a DataFrame, or every simulator's as a list,
    cheapest first, the calibrated one's last) and ``low_fidelity_runs`` (a
    DataFrame for one cheaper level, or a list); DataError for anything else."""
    for name, given in (("runs", runs), ("low_fidelity_runs", low_fidelity_runs)):
        if not (given is None or isinstance(given, pd.DataFrame) or (
                isinstance(given, list | tuple) and all(isinstance(g, pd.DataFrame) for g in given))):
            raise DataError(f"{name}: a DataFrame or a list of DataFrames (cheapest first); "
                            f"got {type(given).__name__}")
    cheaper = [low_fidelity_runs] if isinstance(low_fidelity_runs, pd.DataFrame) else list(low_fidelity_runs)
    if not isinstance(runs, list | tuple):
        return cheaper, runs
    if cheaper or not runs:
        raise DataError("give the simulators' runs either as runs=[cheapest, ..., calibrated] or as "
                        "runs=calibrated with low_fidelity_runs=[...], not both")
    return list(runs[:-1]), runs[-1]


def warn_outside_runs(physical: pd.DataFrame, runs: pd.DataFrame, inputs: Sequence[str], stacklevel: int = 4) -> None:
    """InputRangeWarning for physical inputs beyond the runs' range, where the
    emulator extrapolates; ``stacklevel`` points at the code that built the data."""
    for column in inputs:
        lo, hi = runs[column].min(), runs[column].max()
        values = physical[column].to_numpy()
        outside = (values < lo) | (values > hi)
        if outside.any():
            warnings.warn(f"physical input '{column}' lies outside the simulator runs' range [{lo:g}, {hi:g}] "
                          f"in {_rows(outside, physical.index)}{_of_file(physical)}; the emulator extrapolates there",
                          InputRangeWarning, stacklevel=stacklevel)


def _of_file(frame: pd.DataFrame) -> str:
    """' of dir/physical.csv' after the lines of a table read from a file, else ''."""
    source = source_file(frame.index)
    return f" of {source}" if source else ""


@dataclass(frozen=True)
class Scaling:
    """Affine maps to the unit cube (inputs, covariates, theta) and to a
    standardised output; everything reported goes back through it."""

    low: dict[str, float]
    width: dict[str, float]
    y_center: float
    y_scale: float

    def to_unit(self, frame: pd.DataFrame, columns: Sequence[str]) -> np.ndarray:
        if not columns:
            return np.zeros((len(frame), 0))
        return np.column_stack(
            [(frame[c].to_numpy(float) - self.low[c]) / self.width[c] for c in columns]
        )

    def standardise(self, y: np.ndarray) -> np.ndarray:
        """Outputs in original units -> the standardised scale the programs use."""
        return (np.asarray(y, float) - self.y_center) / self.y_scale

    def original(self, y_standardised: np.ndarray) -> np.ndarray:
        """The inverse of standardise."""
        return self.y_center + self.y_scale * np.asarray(y_standardised, float)


# why a scalar output refuses inputs = [] (a vector output takes it: stancal.problem.vector_data)
NO_INPUTS = ("inputs = []: a scalar output needs at least one simulator input column, since without one every "
             "value measures the same quantity and its discrepancy, a constant, cannot be told from theta; name "
             "the setting the values vary over, or give them as a vector output ([physical] experiment and "
             "output_index), which takes inputs = []")


class CalibrationData:
    """Physical observations, optional simulator runs and the calibration
    parameters of one problem.

    Parameters
    ----------
    physical : DataFrame with the simulator inputs, the output and any
        covariates (measured, but not taken by the simulator).
    inputs : simulator input columns, in the simulator's column order.
    output : the output column (same name in ``runs``).
    theta : calibration parameters in the simulator's order, name -> (lower, upper).
    covariates : extra physical columns the discrepancy may depend on;
        text columns are categorical and enter the discrepancy one-hot.
    runs : simulator runs: the input columns, one column per theta, the output;
        or a list of several simulators' runs, cheapest first, the calibrated
        simulator's last (as ``low_fidelity_runs`` and ``runs``).
    levels : categories of categorical covariates, when they must not be
        taken from ``physical`` (a subset that lacks a level).
    likelihood : gaussian (default), poisson, negbinomial (counts, log link)
        or binomial (successes, logit link). The simulator returns the mean:
        a positive count rate, or a success probability for binomial.
    trials : binomial only: the column with the number of trials (without
        it, the outputs are binary 0/1).
    lower, upper : gaussian only: columns of censoring bounds. A row whose
        output is empty is censored to [lower, upper] (an empty lower is
        -inf, an empty upper +inf); rows with an output are exact.
    low_fidelity_runs : runs of cheaper simulators of the same process (a
        DataFrame for one, or a list, cheapest first), with the columns of ``runs`` (review section 8.3;
        stancal.numerics.multifidelity): the emulator of ``runs`` learns
        from them too.
    theta_low : the cheapest simulator's own calibration parameters theta_l,
        name -> (lower, upper) (Goh et al. 2013): its runs carry these
        columns in place of theta's, and the calibrated simulator is
        rho f_low(x, theta_l) + g(x, theta); theta_l is sampled with theta.
        Two levels only; the names must differ from theta's.
    low_fidelity_rho : the scale between levels, "constant" (default) or
        "linear" in the simulator's inputs, rho(x) = beta_0 + x' beta_x (Le
        Gratiet & Garnier 2014; stancal.problem.fidelity_rho).
    noise_sd : gaussian only: a column of each row's known measurement sd,
        added in quadrature to the estimated noise (stancal.problem.noise).
    source : a column naming each row's measurement source (instrument),
        for one noise sd per source (noise = "per_source").
    sources : the sources, when they must not be taken from ``physical`` (a
        subset, a K-fold training set, that lacks one keeps its sd's index).
    """

    def __init__(
        self,
        physical: pd.DataFrame,
        inputs: Sequence[str],
        output: str,
        theta: Mapping[str, tuple[float, float]],
        covariates: Sequence[str] = (),
        runs: pd.DataFrame | Sequence[pd.DataFrame] | None = None,
        levels: Mapping[str, Sequence[str]] | None = None,
        likelihood: str = "gaussian",
        trials: str | None = None,
        lower: str | None = None,
        upper: str | None = None,
        low_fidelity_runs: pd.DataFrame | Sequence[pd.DataFrame] = (),
        noise_sd: str | None = None,
        source: str | None = None,
        sources: Sequence[str] | None = None,
        theta_low: Mapping[str, tuple[float, float]] | None = None,
        low_fidelity_rho: str = "constant",
    ) -> None:
        self.inputs = list(inputs)
        self.output = output
        self.covariates = list(covariates)
        self.parameters = parameters_from_bounds(theta)
        self.low_parameters = parameters_from_bounds(theta_low or {}, "low-fidelity theta", required=False)
        self._check_names()
        self.source = physical.copy()  # every column, for formulas over the physical data
        what = described("physical data", physical)  # with the file it was read from, if any
        self.levels = self._levels(physical, levels or {}, what)
        numeric = [c for c in self.covariates if c not in self.levels]
        require_columns(physical, [output], what)
        self.observations = read_observations(physical, output, likelihood, trials, lower, upper, what)
        self.noise: MeasurementNoise = read_measurement_noise(physical, noise_sd, source, what, sources)
        self.observation_columns = {"likelihood": likelihood, "trials": trials, "lower": lower, "upper": upper,
                                    "noise_sd": noise_sd, "source": source}
        if noise_sd and not self.observations.is_gaussian:
            raise DataError(f"{what}: a known noise sd (column '{noise_sd}') applies to a gaussian output only; "
                            f"this one's likelihood is '{likelihood}'")
        self.physical = pd.concat([
            numeric_columns(physical, [*self.inputs, *numeric], what),
            pd.DataFrame({output: self.observations.value}, index=physical.index),
            self.one_hot(physical, what)], axis=1)
        if len(self.physical) < 3:
            raise DataError(
                f"{what}: {len(self.physical)} rows; calibration needs at least 3"
            )
        if np.ptp(self.observations.value[self.observations.observed]) == 0 and self.observations.is_gaussian:
            raise DataError(f"{what}: output column '{output}' is constant")
        low_fidelity_runs, runs = simulators_runs(runs, low_fidelity_runs)
        self.runs = None if runs is None else self._check_runs(runs)
        self.low_fidelity_runs = self._check_low_fidelity(low_fidelity_runs)
        self.low_fidelity_rho = check_low_fidelity_rho(low_fidelity_rho, len(self.low_fidelity_runs),
                                                       bool(self.low_parameters))
        if self.runs is not None:  # every simulator's runs teach the emulator
            check_rho_identified(self.low_fidelity_rho, self.runs_by_fidelity(), self.inputs)
            warn_outside_runs(self.physical, pd.concat(self.runs_by_fidelity()), self.inputs, stacklevel=3)
        self.scaling = self._scaling()

    @property
    def theta_names(self) -> list[str]:
        return [p.name for p in self.parameters]

    @property
    def theta_lower(self) -> np.ndarray:
        return np.array([p.lower for p in self.parameters])

    @property
    def theta_upper(self) -> np.ndarray:
        return np.array([p.upper for p in self.parameters])

    @property
    def discrepancy_variables(self) -> dict[str, list[str]]:
        """Each simulator input and covariate -> its discrepancy GP columns
        (one per level for a categorical covariate)."""
        return {c: [c] for c in self.inputs} | covariate_columns(self.covariates, self.levels)

    @property
    def discrepancy_inputs(self) -> list[str]:
        """Columns of the discrepancy GP: simulator inputs, then covariates."""
        return [col for cols in self.discrepancy_variables.values() for col in cols]

    def _levels(self, physical: pd.DataFrame, given: Mapping[str, Sequence[str]], what: str) -> dict[str, list[str]]:
        require_columns(physical, self.covariates, what)
        return covariate_levels(physical, self.covariates, given, what)

    def one_hot(self, frame: pd.DataFrame, what: str = "physical data") -> pd.DataFrame:
        """One 0/1 column per level of each categorical covariate."""
        return one_hot(frame, self.levels, what)

    def _rebuilt(self, source: pd.DataFrame, inputs: Sequence[str] | None = None,
                 theta: Mapping[str, tuple[float, float]] | None = None,
                 covariates: Sequence[str] | None = None, keep_runs: bool = True,
                 runs: pd.DataFrame | None = None) -> CalibrationData:
        """This problem rebuilt (and checked) with some parts changed; same
        categories. ``runs``: other runs in place of these (``keep_runs``
        False: none)."""
        if runs is None and keep_runs:
            runs = self.runs
        return CalibrationData(source, self.inputs if inputs is None else inputs, self.output,
                               bounds_of(self.parameters) if theta is None else theta,
                               self.covariates if covariates is None else covariates,
                               runs, levels=self.levels, sources=self.noise.given_sources, **self.observation_columns,
                               low_fidelity_runs=self.low_fidelity_runs if runs is not None else (),
                               theta_low=bounds_of(self.low_parameters) if runs is not None else None,
                               low_fidelity_rho=self.low_fidelity_rho if runs is not None else "constant")

    def subset(self, rows: Sequence[int]) -> CalibrationData:
        """The same problem on some physical rows (positions), same categories."""
        return self._rebuilt(self.source.iloc[list(rows)])

    def with_runs(self, runs: pd.DataFrame) -> CalibrationData:
        """The same problem with other simulator runs (every run, as ``runs``), checked as runs are."""
        return self._rebuilt(self.source, runs=runs)

    def variant(self, inputs: Sequence[str], extra_theta: Mapping[str, tuple[float, float]]) -> CalibrationData:
        """The problem as a simulator variant sees it: its own inputs and
        theta (this one's, then its extra ones), no runs; the discrepancy
        keeps every variable of this one."""
        return self._rebuilt(self.source, inputs, bounds_of(self.parameters) | dict(extra_theta),
                             [v for v in self.discrepancy_variables if v not in inputs], keep_runs=False)

    def with_output(self, y: np.ndarray) -> CalibrationData:
        """The same problem with other outputs (simulated ones) and this
        problem's scaling kept: the programs' priors live on the
        standardised scale, so a fit of simulated data must standardise as
        the simulation did. Censored data censor the new values as the lab
        did: a value inside one of the censoring ranges this data has (each
        distinct lower, upper pair) is reported as that range."""
        source = self.source.copy()
        y = np.asarray(y)
        source[self.output] = y
        observations = self.observations
        if observations.any_censored:
            lower, upper = self.observation_columns["lower"], self.observation_columns["upper"]
            censored = ~observations.observed
            ranges = sorted(set(zip(observations.lower[censored], observations.upper[censored], strict=False)))
            for column in (lower, upper):
                if column:
                    source[column] = np.nan
            for low, high in ranges:
                inside = (y >= low) & (y <= high)
                source.loc[inside, self.output] = np.nan
                if lower and np.isfinite(low):
                    source.loc[inside, lower] = low
                if upper and np.isfinite(high):
                    source.loc[inside, upper] = high
        other = self._rebuilt(source)
        other.scaling = self.scaling
        return other

    @property
    def latent_reason(self) -> str | None:
        """Why the outputs need the latent-GP programs (the GP cannot be
        integrated out), or None."""
        if not self.observations.is_gaussian:
            return f"likelihood '{self.observations.likelihood.name.lower()}'"
        if self.observations.any_censored:
            return "censored outputs"
        return None

    @property
    def discrepancy_scale(self) -> str:
        """What the discrepancy is measured in (output units, or a link scale)."""
        return LINKS[self.observations.likelihood].scale

    def heldout_log_density(self, rows: np.ndarray, zeta: np.ndarray, posterior,
                            estimated_sd: np.ndarray | None = None) -> np.ndarray:
        """log p(y_row | zeta, the fit's noise or dispersion) per draw (draws, rows):
        each row's noise scale from its source and known sd, Student-t where
        the fit has degrees of freedom nu (stancal.problem.noise);
        ``estimated_sd``: the estimated sd at the rows per draw (heteroscedastic
        noise), in place of the posterior's noise_sd."""
        phi = np.asarray(posterior["phi"]).reshape(-1, 1) if "phi" in posterior else None
        nu = np.asarray(posterior["nu"]).reshape(-1, 1) if "nu" in posterior else None
        noise = None
        if estimated_sd is not None:
            noise = with_known_sd(estimated_sd, self.noise.known_sd[rows])
        elif "noise_sd" in posterior:
            sigma = np.asarray(posterior["noise_sd"]).reshape(len(zeta), -1)
            noise = row_noise_sd(sigma, self.noise.source_index[rows], self.noise.known_sd[rows])
        return self.observations.log_density(rows, zeta, noise, phi, nu)

    @property
    def discrepancy_units(self) -> float:
        """Output units per model-scale unit of the discrepancy: the output's
        scale for Gaussian outputs (standardised), 1 on a link scale (the
        Stan programs' discrepancy_units)."""
        return self.scaling.y_scale if self.observations.is_gaussian else 1.0

    def trials_at(self, points: pd.DataFrame) -> np.ndarray:
        """Binomial trials of a new observation at each point: the trials
        column where the points have it, else one (a binary outcome)."""
        column = self.observation_columns["trials"]
        if column is None or column not in points:
            return np.ones(len(points), dtype=int)
        values = numeric_values(points, column, "prediction points")
        require_whole(values, column, points.index, "prediction points", 1)
        return values.astype(int)

    @property
    def has_runs(self) -> bool:
        return self.runs is not None

    def _check_names(self) -> None:
        if not self.inputs:  # every scalar program's emulator and discrepancy vary over D >= 1 inputs
            raise DataError(NO_INPUTS)
        named = [*self.inputs, *self.covariates, self.output]
        repeated = sorted({n for n in named if named.count(n) > 1})
        if repeated:
            raise DataError(f"column(s) {repeated} named more than once among inputs, covariates and output")
        clash = sorted(set(self.theta_names) & set(named))
        if clash:
            raise DataError(f"theta name(s) {clash} clash with data column names")

    def _check_runs(self, runs: pd.DataFrame, parameters: Sequence[Parameter] | None = None) -> pd.DataFrame:
        """Runs with the inputs, ``parameters`` (default theta) and the output, checked."""
        parameters = self.parameters if parameters is None else parameters
        what = described("simulator runs", runs)
        table = numeric_columns(runs, [*self.inputs, *(p.name for p in parameters), self.output], what)
        if len(table) < 3:
            raise DataError(f"{what}: {len(table)} rows; an emulator needs at least 3")
        if np.ptp(table[self.output].to_numpy()) == 0:
            raise DataError(f"{what}: output column '{self.output}' is constant")
        self._check_runs_on_link_scale(table)
        require_runs_within_bounds(table, parameters)
        return table

    def _check_low_fidelity(self, given: Sequence[pd.DataFrame]) -> list[pd.DataFrame]:
        """Cheaper simulators' runs, checked as runs are; they need the calibrated simulator's runs."""
        if given and self.runs is None:
            raise DataError("low-fidelity runs need the runs of the simulator being calibrated (runs = ...): "
                            "the cheaper runs inform its emulator")
        check_low_fidelity_theta(self.parameters, self.low_parameters, given,
                                 [*self.inputs, *self.covariates, self.output])
        return [self._check_runs(runs, self.low_parameters or None) if level == 0 else self._check_runs(runs)
                for level, runs in enumerate(given)]

    @property
    def theta_low_names(self) -> list[str]:
        """The cheapest simulator's own theta_l (empty: the levels share theta)."""
        return [p.name for p in self.low_parameters]

    @property
    def fidelities(self) -> int:
        """How many simulators of the process have runs: 1, or more with low-fidelity runs."""
        return 1 + len(self.low_fidelity_runs)

    def runs_by_fidelity(self) -> list[pd.DataFrame]:
        """Every simulator's runs, cheapest first, the calibrated one's last."""
        return [*self.low_fidelity_runs, *([] if self.runs is None else [self.runs])]

    def run_count(self) -> int:
        """Runs of every fidelity."""
        return sum(len(r) for r in self.runs_by_fidelity())

    def _check_runs_on_link_scale(self, table: pd.DataFrame) -> None:
        """The runs' output is the simulator's mean: it must lie where the link is defined."""
        link = LINKS[self.observations.likelihood]
        values = table[self.output].to_numpy()
        bad = ~link.defined(values)
        if bad.any():
            raise DataError(f"{described('simulator runs', table)}: output column '{self.output}' must be "
                            f"{link.requirement}; "
                            f"{_rows(bad, table.index)} hold {values[bad][:5].tolist()}")

    def runs_on_link_scale(self, runs: pd.DataFrame | None = None) -> np.ndarray:
        """The runs' output (by default the calibrated simulator's) on the likelihood's link scale."""
        runs = self.runs if runs is None else runs
        assert runs is not None
        return LINKS[self.observations.likelihood].transform(runs[self.output].to_numpy())

    def _scaling(self) -> Scaling:
        low, width = {}, {}
        for column in self.discrepancy_inputs:
            values = self.physical[column].to_numpy()
            for runs in self.runs_by_fidelity():  # every run inside the unit cube
                if column in runs:
                    values = np.concatenate([values, runs[column].to_numpy()])
            low[column] = float(values.min())
            width[column] = float(np.ptp(values)) or 1.0
        for p in [*self.parameters, *self.low_parameters]:
            low[p.name], width[p.name] = p.lower, p.upper - p.lower
        # With runs, the emulator sees mostly simulator output: standardise by it
        # (on the link scale). A cheap simulator's link scale is left as it is.
        if self.runs is not None:
            reference = self.runs_on_link_scale()
        elif self.observations.is_gaussian:
            reference = self.observations.value[self.observations.observed]
        else:
            return Scaling(low, width, 0.0, 1.0)
        return Scaling(low, width, float(reference.mean()), float(reference.std()) or 1.0)

    def check_new_points(self, new: pd.DataFrame) -> pd.DataFrame:
        """Validated prediction points: the inputs and covariates as in the
        physical data, returned with categorical covariates one-hot."""
        table = pd.concat([new.drop(columns=list(self.levels), errors="ignore"),
                           self.one_hot(new, "prediction points")], axis=1)
        return numeric_columns(table, self.discrepancy_inputs, "prediction points")

    def to_dict(self) -> dict:
        return {
            "physical": self.source.to_dict(orient="list"),
            "inputs": self.inputs,
            "output": self.output,
            "covariates": self.covariates,
            "theta": {p.name: [p.lower, p.upper] for p in self.parameters},
            "runs": None if self.runs is None else self.runs.to_dict(orient="list"),
            "low_fidelity_runs": [runs.to_dict(orient="list") for runs in self.low_fidelity_runs],
            "theta_low": bounds_of(self.low_parameters),
            "low_fidelity_rho": self.low_fidelity_rho,
            "levels": self.levels,
            "sources": self.noise.given_sources,
            **self.observation_columns,
        }

    @classmethod
    def from_dict(cls, d: dict) -> CalibrationData:
        runs = None if d["runs"] is None else pd.DataFrame(d["runs"])
        return cls(pd.DataFrame(d["physical"]), d["inputs"], d["output"],
                   {k: tuple(v) for k, v in d["theta"].items()}, d["covariates"], runs,
                   levels=d.get("levels"), sources=d.get("sources"), likelihood=d.get("likelihood", "gaussian"),
                   trials=d.get("trials"), lower=d.get("lower"), upper=d.get("upper"),
                   noise_sd=d.get("noise_sd"), source=d.get("source"),
                   low_fidelity_runs=[pd.DataFrame(r) for r in d.get("low_fidelity_runs", [])],
                   theta_low={k: tuple(v) for k, v in d.get("theta_low", {}).items()},
                   low_fidelity_rho=d.get("low_fidelity_rho", "constant"))
