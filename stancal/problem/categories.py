"""Categorical covariates, shared by scalar and vector outputs: a text
column's levels, and one 0/1 column per level, each with its own relevance
(inverse length scale) in the discrepancy GP of Kennedy & O'Hagan (2001).
Over the one-hot coding a squared-exponential kernel correlates levels j and
k by exp(-(r_j^2 + r_k^2) / 2): a special case of the qualitative-factor
correlations of Qian, Wu & Wu (2008, Technometrics 50), with automatic
relevance determination (Rasmussen & Williams 2006, section 5.1) deciding
whether the levels differ at all."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
import pandas as pd

from stancal.problem.validation import DataError, row_labels


def one_hot_name(column: str, level: str) -> str:
    """The discrepancy column of one level: 'cup[glass]'."""
    return f"{column}[{level}]"


def category_levels(frame: pd.DataFrame, column: str, what: str) -> list[str] | None:
    """Levels of a text column, or None for a numeric one; a column that
    mixes numbers and text, or a text column with empty rows, is an error
    naming the rows."""
    raw = frame[column]
    if pd.api.types.is_numeric_dtype(raw):
        return None
    numeric = pd.to_numeric(raw, errors="coerce").notna().to_numpy()
    missing = raw.isna().to_numpy()
    if numeric[~missing].all():
        return None
    if numeric.any():
        raise DataError(f"{what}: column '{column}' mixes numbers and text; numbers in "
                        f"{row_labels(numeric, frame.index)}")
    if missing.any():
        raise DataError(f"{what}: categorical column '{column}' is empty in {row_labels(missing, frame.index)}")
    return sorted(raw.astype(str).unique())


def covariate_levels(frame: pd.DataFrame, covariates: Sequence[str], given: Mapping[str, Sequence[str]],
                     what: str) -> dict[str, list[str]]:
    """column -> levels of each categorical covariate: ``given`` (a subset's
    parent's, which may hold a level the subset lacks), else the column's."""
    out = {}
    for column in covariates:
        found = category_levels(frame, column, what)
        if found is not None:
            out[column] = list(given.get(column, found))
    return out


def one_hot(frame: pd.DataFrame, levels: Mapping[str, Sequence[str]], what: str) -> pd.DataFrame:
    """One 0/1 column per level of each categorical covariate; a level not
    among ``levels`` is an error naming the rows."""
    columns = {}
    for column, names in levels.items():
        if column not in frame.columns:
            raise DataError(f"{what}: missing categorical column '{column}'")
        values = frame[column].astype(str).to_numpy()
        unknown = ~np.isin(values, names)
        if unknown.any():
            raise DataError(f"{what}: column '{column}' has levels not in {list(names)} in "
                            f"{row_labels(unknown, frame.index)}")
        for level in names:
            columns[one_hot_name(column, level)] = (values == level).astype(float)
    return pd.DataFrame(columns, index=frame.index)


def covariate_columns(covariates: Sequence[str], levels: Mapping[str, Sequence[str]]) -> dict[str, list[str]]:
    """Each covariate -> its discrepancy GP columns: itself, or one per level."""
    return {c: [one_hot_name(c, v) for v in levels[c]] if c in levels else [c] for c in covariates}
