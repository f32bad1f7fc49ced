"""The error for unusable input data, and how rows are named in it."""

from __future__ import annotations

import numpy as np
import pandas as pd


class DataError(ValueError):
    """Input data that cannot be used, with the column and rows to fix."""


def row_labels(mask: np.ndarray, index: pd.Index, limit: int = 10) -> str:
    """'[3, 17, ... 4 more]': the labels of the rows where mask is true."""
    labels = [str(v) for v in index[mask][:limit]]
    more = int(mask.sum()) - len(labels)
    return "[" + ", ".join(labels) + (f", ... {more} more" if more > 0 else "") + "]"


def numeric_values(frame: pd.DataFrame, column: str, what: str) -> np.ndarray:
    """A column as floats, NaN where empty; text is an error naming the rows."""
    raw = frame[column]
    values = pd.to_numeric(raw, errors="coerce")
    bad = values.isna().to_numpy() & raw.notna().to_numpy()
    if bad.any():
        raise DataError(f"{what}: column '{column}' has non-numeric values in rows {row_labels(bad, frame.index)}")
    return values.to_numpy(dtype=float)


def require_whole(values: np.ndarray, column: str, index: pd.Index, what: str, minimum: int) -> None:
    """Whole numbers >= minimum (0 for counts, 1 for trials)."""
    bad = np.isnan(values) | (values < minimum) | (values != np.round(values))
    if bad.any():
        kind = "non-negative" if minimum == 0 else "positive"
        raise DataError(f"{what}: column '{column}' must hold {kind} whole numbers; rows "
                        f"{row_labels(bad, index)} hold {values[bad][:5].tolist()}")
