"""The user's Stan simulator checked at the data's rows before sampling, on
the program already compiled: the log density once at the first chain's
start, where the programs' standardized_simulator (functions/
simulator_output.stan) evaluates it. A wrong length or a non-finite value
becomes one line naming the simulator's file and the data's file and line."""

from __future__ import annotations

import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from stancal.problem.validation import source_file
from stancal.stan.backends import StanRuntimeError
from stancal.stan.source import FlatProgram

# Stan's size check where standardized_simulator stores simulator(X, theta) in vector[rows(X)] f
_LENGTH = re.compile(r"assigning variable f \((\d+)\) and right hand side rows \((\d+)\)")
# standardized_simulator's and the observation model's reject() messages
_REJECTED = re.compile(r"simulator\(X, theta\) returned (.+?) at row (\d+) of X = \[([^\]]*)\]"
                       r"(?: with theta = \[([^\]]*)\])?(;[^(]*)?")
_CHECKS = "simulator_output.stan"


def simulator_failure(message: str, simulator: Path, points: pd.DataFrame) -> str | None:
    """One line for a Stan message about the simulator, or None when the
    message is about something else. ``points``: the rows of X in the
    program's order (the data's lines in their index when read from a file)."""
    name = simulator.name
    length = _LENGTH.search(message)
    if length and _CHECKS in message:
        return (f"{name} returned {length.group(2)} values for {length.group(1)} rows; it must return one value "
                f"per row of X")
    rejected = _REJECTED.search(message)
    if rejected:
        value, row, x, theta, reason = rejected.groups()
        where = _where(int(row), [float(v) for v in x.split(",") if v.strip()], points)
        return (f"{name} returned {value} at row {row} ({where})" + (f" with theta = [{theta}]" if theta else "")
                + (reason or "").rstrip())
    if str(simulator) in message:  # Stan stopped inside the user's file (an index out of range, ...)
        return f"{name} failed at the data's rows: {' '.join(message.split())}"
    return None


def _where(row: int, x: Sequence[float], points: pd.DataFrame) -> str:
    """'line 14 of physical.csv' for X's row, found by its values (the
    vector programs call the simulator on one experiment's rows at a time)."""
    values = points.to_numpy(float)
    at = row - 1
    if not (0 <= at < len(values) and len(x) == values.shape[1] and np.allclose(values[at], x, rtol=1e-5)):
        same = np.flatnonzero(np.all(np.isclose(values, x, rtol=1e-5), axis=1)) if len(x) == values.shape[1] else []
        if not len(same):
            return f"X = [{', '.join(f'{v:g}' for v in x)}]"
        at = int(same[0])
    source = source_file(points.index)
    return f"line {points.index[at]} of {source}" if source else f"data row {at + 1}"


def check_simulator_at_start(stan_backend, program: FlatProgram, data: dict[str, Any],
                             inits: list[dict[str, Any]] | None, simulator: Path | None,
                             points: pd.DataFrame) -> None:
    """Raise StanRuntimeError with one line if the simulator fails at the
    data's rows at the first chain's start; other failures there are left
    to the sampler (it starts the other parameters at random)."""
    if simulator is None:
        return
    message = stan_backend.start_error(program, data, inits)
    failure = message and simulator_failure(message, simulator, points)
    if failure:
        raise StanRuntimeError(failure)


def explained(err: StanRuntimeError, simulator: Path | None, points: pd.DataFrame) -> StanRuntimeError:
    """A sampler's failure, as one line when the simulator caused it."""
    failure = simulator is not None and simulator_failure(str(err), simulator, points)
    return StanRuntimeError(failure) if failure else err
