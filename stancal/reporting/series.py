"""The curves of a scalar calibration's figures: the input the data vary
most along, the series of rows that share the other simulator inputs (the
cooling case's three starting temperatures), and a fine grid along that
input per series, where zeta, f and delta are predicted so that a series
with few points still shows as a curve."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

# more series than this are no longer told apart by colour: the figure then
# shows the predictions at the data points instead of curves
MAX_SERIES = 6
# prediction points over all series, and posterior draws they are predicted
# at: generated quantities are rerun per draw, at a cost that grows faster
# than the points (koh_emulator on pipe_flow: 72 s for 600 draws x 240 points)
GRID_POINTS = 160
GRID_DRAWS = 200


@dataclass
class Curves:
    """Predictions (result.predict's columns plus ``series``) along ``along``."""

    along: str
    table: pd.DataFrame
    labels: list[str]  # one per series ("T0 = 60 °C"); [""] for a single series
    held: str  # how the covariates are held along a curve, in words ("" without covariates)
    on_grid: bool  # False: at the data points, too many series for curves


def axis_label(name: str, units: dict[str, str] | None) -> str:
    """``name [unit]`` when the config's [units] gives one, else the name."""
    return f"{name} [{units[name]}]" if units and units.get(name) else name


def along_input(data, functional_inputs: tuple[str, ...] | list[str] = ()) -> str:
    """The simulator input, or input of a functional theta (which reality
    varies along, like the beam's temperature), with the most distinct
    values in the data (the first on a tie)."""
    counts = {c: data.physical[c].nunique() for c in dict.fromkeys([*data.inputs, *functional_inputs])}
    return max(counts, key=counts.__getitem__)


def series_rows(data, along: str) -> list[tuple[dict, np.ndarray]] | None:
    """(the other simulator inputs' values, row positions) per series, or
    None when there are more than MAX_SERIES of them."""
    others = [c for c in data.inputs if c != along]
    if not others:
        return [({}, np.arange(len(data.physical)))]
    groups = data.physical.reset_index(drop=True).groupby(others, sort=True).indices
    if len(groups) > MAX_SERIES:
        return None
    return [(dict(zip(others, key if isinstance(key, tuple) else (key,), strict=True)), rows)
            for key, rows in groups.items()]


def _grid(data, along: str, series: list[tuple[dict, np.ndarray]]) -> pd.DataFrame:
    """GRID_POINTS along ``along`` over each series' range, covariates at the
    series' mean (numeric) or most frequent level (categorical)."""
    source = data.source.reset_index(drop=True)
    size = max(25, GRID_POINTS // len(series))
    frames = []
    for s, (fixed, rows) in enumerate(series):
        values = source[along].iloc[rows]
        frame = pd.DataFrame({along: np.linspace(values.min(), values.max(), size), **fixed})
        for c in (c for c in data.covariates if c != along):
            column = source[c].iloc[rows]
            frame[c] = column.mode().iloc[0] if c in data.levels else column.mean()
        frames.append(frame.assign(series=s))
    return pd.concat(frames, ignore_index=True)


def _held(data, along: str) -> str:
    numeric = [c for c in data.covariates if c not in data.levels and c != along]
    categorical = [c for c in data.covariates if c in data.levels]
    parts = ([f"{', '.join(numeric)} at the series' mean"] if numeric else []) + \
        ([f"{', '.join(categorical)} at the series' most frequent level"] if categorical else [])
    return "; ".join(parts)


def _series_label(fixed: dict, units: dict[str, str] | None) -> str:
    return ", ".join(f"{k} = {v:g}" + (f" {units[k]}" if units and units.get(k) else "") for k, v in fixed.items())


def fit_curves(result, units: dict[str, str] | None = None) -> Curves:
    """zeta, f and delta along the input the data vary most along, one
    curve per series. A single discrepancy input uses the fit's own grid;
    more series than MAX_SERIES use the fit's predictions at the data points."""
    data = result.data
    along = along_input(data, result.options.functional_inputs)
    series = series_rows(data, along)
    if len(data.discrepancy_inputs) == 1 or series is None:  # the fit's own grid, or the data points
        return Curves(along, result.predict().assign(series=0), [""], "", len(data.discrepancy_inputs) == 1)
    grid = _grid(data, along, series)
    table = result.predict(grid.drop(columns="series"), max_draws=GRID_DRAWS).assign(series=grid["series"].to_numpy())
    return Curves(along, table, [_series_label(fixed, units) for fixed, _ in series], _held(data, along), True)
