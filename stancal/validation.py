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
