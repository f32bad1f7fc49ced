"""The error for unusable input data, and how rows are named in it: a
table read from a file keeps the file's line numbers as its index (the
header is line 1), so an error names the file and the lines to fix."""

from __future__ import annotations

import csv
import io
from pathlib import Path

import numpy as np
import pandas as pd

_LINES_OF = "line of "  # the index name of a table read by read_table: "line of <file>"


class DataError(ValueError):
    """Input data that cannot be used, with the column and rows to fix."""


def read_table(path: Path) -> pd.DataFrame:
    """A CSV file whose index is each row's line in the file (the header is
    line 1), named after the file. An empty file, a header that repeats a
    column, a row with more or fewer fields than the header, or a file
    pandas cannot parse is a DataError naming the file (and the line)."""
    try:
        text = path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError as err:
        raise DataError(f"{path}: not a UTF-8 text file ({err.reason} at byte {err.start})") from None
    try:
        reader = csv.reader(io.StringIO(text))
        rows, last = [], 0
        for row in reader:  # a row starts on the line after the last one ended (a quoted field may span lines)
            if any(field.strip() for field in row):
                rows.append((last + 1, row))
            last = reader.line_num
    except csv.Error as err:
        raise DataError(f"{path}: cannot read as CSV: {err}") from None
    if not rows:
        raise DataError(f"{path}: the file is empty; it needs a header line and data rows")
    (header_line, header), data = rows[0], rows[1:]
    names = [name.strip() for name in header]
    repeated = sorted({name for name in names if names.count(name) > 1})
    if repeated:
        raise DataError(f"{path}: line {header_line} (the header) repeats column(s) {repeated}")
    ragged = [(line, len(row)) for line, row in data if len(row) != len(header)]
    if ragged:  # pandas would shift such a row into an index, or fill it silently
        line, count = ragged[0]
        raise DataError(f"{path}: line {line} has {count} fields; the header (line {header_line}) has {len(header)}"
                        + (f" ({len(ragged) - 1} more such lines)" if len(ragged) > 1 else ""))
    try:
        frame = pd.read_csv(io.StringIO(text))
    except Exception as err:  # pandas raises many parser errors
        raise DataError(f"{path}: cannot read as CSV: {' '.join(str(err).split())}") from None
    lines = [line for line, _ in data] if len(data) == len(frame) else range(2, len(frame) + 2)
    frame.index = pd.Index(lines, name=f"{_LINES_OF}{path}")
    return frame


def source_file(index: pd.Index) -> str | None:
    """The file a table was read from by read_table, or None."""
    name = index.name
    return name[len(_LINES_OF):] if isinstance(name, str) and name.startswith(_LINES_OF) else None


def described(what: str, frame: pd.DataFrame) -> str:
    """'physical data (dir/physical.csv)' for a table read from a file, else what."""
    source = source_file(frame.index)
    return f"{what} ({source})" if source else what


def row_labels(mask: np.ndarray, index: pd.Index, limit: int = 10) -> str:
    """'lines [3, 17, ... 4 more]' of a table read from a file, else 'rows
    [3, 17]' (the index's labels) where mask is true."""
    labels = [str(v) for v in index[mask][:limit]]
    more = int(mask.sum()) - len(labels)
    kind = "lines" if source_file(index) else "rows"
    return f"{kind} [" + ", ".join(labels) + (f", ... {more} more" if more > 0 else "") + "]"


def numeric_values(frame: pd.DataFrame, column: str, what: str) -> np.ndarray:
    """A column as floats, NaN where empty; text is an error naming the rows."""
    raw = frame[column]
    values = pd.to_numeric(raw, errors="coerce")
    bad = values.isna().to_numpy() & raw.notna().to_numpy()
    if bad.any():
        raise DataError(f"{what}: column '{column}' has non-numeric values in {row_labels(bad, frame.index)}")
    return values.to_numpy(dtype=float)


def require_whole(values: np.ndarray, column: str, index: pd.Index, what: str, minimum: int) -> None:
    """Whole numbers >= minimum (0 for counts, 1 for trials)."""
    bad = np.isnan(values) | (values < minimum) | (values != np.round(values))
    if bad.any():
        kind = "non-negative" if minimum == 0 else "positive"
        raise DataError(f"{what}: column '{column}' must hold {kind} whole numbers; "
                        f"{row_labels(bad, index)} hold {values[bad][:5].tolist()}")
