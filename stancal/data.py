"""One validated container for a calibration problem: physical data,
optional simulator runs, and the calibration parameters with their bounds."""

from __future__ import annotations

import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd


class DataError(ValueError):
    """Input data that cannot be used, with the column and rows to fix."""


class InputRangeWarning(UserWarning):
    """Physical inputs outside the range covered by the simulator runs."""


@dataclass(frozen=True)
class Parameter:
    """A calibration parameter; its bounds are the support of a uniform prior."""

    name: str
    lower: float
    upper: float


def _rows(mask: np.ndarray, index: pd.Index, limit: int = 10) -> str:
    labels = [str(v) for v in index[mask][:limit]]
    more = int(mask.sum()) - len(labels)
    return "[" + ", ".join(labels) + (f", ... {more} more" if more > 0 else "") + "]"


def _numeric_columns(frame: pd.DataFrame, columns: Sequence[str], what: str) -> pd.DataFrame:
    """The named columns as floats, or a DataError naming the column and rows."""
    if frame.columns.duplicated().any():
        dup = sorted(set(frame.columns[frame.columns.duplicated()]))
        raise DataError(f"{what}: duplicate column(s) {dup}")
    missing = [c for c in columns if c not in frame.columns]
    if missing:
        raise DataError(
            f"{what}: missing column(s) {missing}; available: {list(frame.columns)}"
        )
    out = {}
    for column in columns:
        raw = frame[column]
        values = pd.to_numeric(raw, errors="coerce")
        bad = values.isna().to_numpy() & raw.notna().to_numpy()
        if bad.any():
            raise DataError(
                f"{what}: column '{column}' has non-numeric values in rows {_rows(bad, frame.index)}"
            )
        values = values.to_numpy(dtype=float)
        bad = ~np.isfinite(values)
        if bad.any():
            raise DataError(
                f"{what}: column '{column}' has NaN or inf in rows {_rows(bad, frame.index)}"
            )
        out[column] = values
    return pd.DataFrame(out, index=frame.index)


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
    covariates : extra physical columns the discrepancy may depend on.
    runs : simulator runs: the input columns, one column per theta, the output.
    """

    def __init__(
        self,
        physical: pd.DataFrame,
        inputs: Sequence[str],
        output: str,
        theta: Mapping[str, tuple[float, float]],
        covariates: Sequence[str] = (),
        runs: pd.DataFrame | None = None,
    ) -> None:
        self.inputs = list(inputs)
        self.output = output
        self.covariates = list(covariates)
        self.parameters = self._parameters(theta)
        self._check_names()
        self.physical = _numeric_columns(
            physical, [*self.inputs, *self.covariates, output], "physical data"
        )
        if len(self.physical) < 3:
            raise DataError(
                f"physical data: {len(self.physical)} rows; calibration needs at least 3"
            )
        if np.ptp(self.physical[output].to_numpy()) == 0:
            raise DataError(f"physical data: output column '{output}' is constant")
        self.runs = None if runs is None else self._check_runs(runs)
        self.scaling = self._scaling()

    @property
    def theta_names(self) -> list[str]:
        return [p.name for p in self.parameters]

    @property
    def discrepancy_inputs(self) -> list[str]:
        """Inputs of the discrepancy GP: simulator inputs, then covariates."""
        return [*self.inputs, *self.covariates]

    @property
    def has_runs(self) -> bool:
        return self.runs is not None

    @staticmethod
    def _parameters(theta: Mapping[str, tuple[float, float]]) -> list[Parameter]:
        if not theta:
            raise DataError("theta: give at least one calibration parameter with bounds")
        out = []
        for name, bounds in theta.items():
            try:
                lower, upper = (float(b) for b in bounds)
            except (TypeError, ValueError):
                raise DataError(
                    f"theta '{name}': bounds must be two numbers [lower, upper]; got {bounds!r}"
                ) from None
            if not (np.isfinite(lower) and np.isfinite(upper) and lower < upper):
                raise DataError(
                    f"theta '{name}': bounds must be finite with lower < upper; got [{lower}, {upper}]"
                )
            out.append(Parameter(name, lower, upper))
        return out

    def _check_names(self) -> None:
        if not self.inputs:
            raise DataError("inputs: give at least one simulator input column")
        named = [*self.inputs, *self.covariates, self.output]
        repeated = sorted({n for n in named if named.count(n) > 1})
        if repeated:
            raise DataError(f"column(s) {repeated} named more than once among inputs, covariates and output")
        clash = sorted(set(self.theta_names) & set(named))
        if clash:
            raise DataError(f"theta name(s) {clash} clash with data column names")

    def _check_runs(self, runs: pd.DataFrame) -> pd.DataFrame:
        table = _numeric_columns(runs, [*self.inputs, *self.theta_names, self.output], "simulator runs")
        if len(table) < 3:
            raise DataError(f"simulator runs: {len(table)} rows; an emulator needs at least 3")
        if np.ptp(table[self.output].to_numpy()) == 0:
            raise DataError(f"simulator runs: output column '{self.output}' is constant")
        for p in self.parameters:
            values = table[p.name].to_numpy()
            bad = (values < p.lower) | (values > p.upper)
            if bad.any():
                raise DataError(
                    f"simulator runs: column '{p.name}' lies outside its bounds "
                    f"[{p.lower}, {p.upper}] in rows {_rows(bad, table.index)}"
                )
        for column in self.inputs:
            lo, hi = table[column].min(), table[column].max()
            values = self.physical[column].to_numpy()
            outside = (values < lo) | (values > hi)
            if outside.any():
                warnings.warn(
                    f"physical input '{column}' lies outside the simulator runs' range "
                    f"[{lo:g}, {hi:g}] in rows {_rows(outside, self.physical.index)}; "
                    "the emulator extrapolates there",
                    InputRangeWarning,
                    stacklevel=3,
                )
        return table

    def _scaling(self) -> Scaling:
        low, width = {}, {}
        for column in self.discrepancy_inputs:
            values = self.physical[column].to_numpy()
            if self.runs is not None and column in self.runs:
                values = np.concatenate([values, self.runs[column].to_numpy()])
            low[column] = float(values.min())
            width[column] = float(np.ptp(values)) or 1.0
        for p in self.parameters:
            low[p.name], width[p.name] = p.lower, p.upper - p.lower
        # With runs, the emulator sees mostly simulator output: standardise by it.
        reference = (self.runs if self.runs is not None else self.physical)[self.output].to_numpy()
        return Scaling(low, width, float(reference.mean()), float(reference.std()) or 1.0)

    def check_new_points(self, new: pd.DataFrame) -> pd.DataFrame:
        """Validated prediction points (the inputs and covariates)."""
        return _numeric_columns(new, self.discrepancy_inputs, "prediction points")

    def to_dict(self) -> dict:
        return {
            "physical": self.physical.to_dict(orient="list"),
            "inputs": self.inputs,
            "output": self.output,
            "covariates": self.covariates,
            "theta": {p.name: [p.lower, p.upper] for p in self.parameters},
            "runs": None if self.runs is None else self.runs.to_dict(orient="list"),
        }

    @classmethod
    def from_dict(cls, d: dict) -> "CalibrationData":
        runs = None if d["runs"] is None else pd.DataFrame(d["runs"])
        return cls(pd.DataFrame(d["physical"]), d["inputs"], d["output"],
                   {k: tuple(v) for k, v in d["theta"].items()}, d["covariates"], runs)
