"""A stopped command resumes: rerun with the same output folder, a command
that makes many fits (gap, compare, SBC) reuses every fit it finished there
with the same inputs, and runs only the others. Its seeds are fixed (the
command's seed is kept in the folder), so a reused fit is the fit the rerun
would make.

A fit is finished when its folder holds a record, ``finished.json``,
written after everything else the fit writes, as a temporary file renamed
over the record (os.replace), so that a command stopped at any moment
leaves either a whole record or none. The record holds the fit's
fingerprint, one hash per input of the fit (its data by content, the plan
with its Stan programs' code, the sampling options, the seed), and what the
command keeps of the fit's value beyond its files. A record whose
fingerprint differs is a fit of other inputs: it is run again, and the
inputs that changed are named.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
import os
from collections.abc import Callable, Mapping
from enum import Enum
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from stancal.fitting.cluster import FitRunner, FitTask
from stancal.fitting.plan import Plan
from stancal.fitting.seeds import command_seed

logger = logging.getLogger("stancal")

RECORD = "finished.json"
SEED_RECORD = "seed.json"  # the command's seed, for a rerun without --seed
FOLDER_KEYWORD = "out_dir"  # the task's keyword naming the folder its fit is written to
NAMES_SAID = 4  # fits named in a line about several


def _sha(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def _frame(value: pd.DataFrame | pd.Series | pd.Index) -> dict[str, Any]:
    frame = value.to_frame() if isinstance(value, pd.Series | pd.Index) else value
    return {"columns": [str(c) for c in frame.columns], "dtypes": [str(t) for t in frame.dtypes],
            "sha256": _sha(pd.util.hash_pandas_object(value, index=True).to_numpy().tobytes())}


def canonical(value: Any) -> Any:
    """``value`` as JSON that is the same in every process for equal inputs:
    no object ids, no set order, tables and arrays by content, a file by its
    content (not its name), a function by its qualified name, a plan with
    its programs' code (their includes resolved)."""
    if value is None or isinstance(value, bool | int | float | str):
        return value
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, Enum):
        return value.name
    if isinstance(value, Path):
        return {"file": _sha(value.read_bytes())} if value.is_file() else {"path": str(value)}
    if isinstance(value, np.ndarray):
        if value.dtype == object:
            return [canonical(v) for v in value.tolist()]
        return {"dtype": value.dtype.str, "shape": list(value.shape),
                "sha256": _sha(np.ascontiguousarray(value).tobytes())}
    if isinstance(value, pd.DataFrame | pd.Series | pd.Index):
        return _frame(value)
    if isinstance(value, Mapping):
        return {str(k): canonical(v) for k, v in sorted(value.items(), key=lambda item: str(item[0]))}
    if isinstance(value, list | tuple):
        return [canonical(v) for v in value]
    if isinstance(value, set | frozenset):
        return sorted((canonical(v) for v in value), key=json.dumps)
    if isinstance(value, Plan):  # its files' includes count too
        return {"fields": _fields(value), "code": [p.code for p in value.stan_programs()]}
    if dataclasses.is_dataclass(value):
        return _fields(value)
    if callable(value) and hasattr(value, "__qualname__"):
        return f"{value.__module__}.{value.__qualname__}"
    if hasattr(value, "__dict__"):
        return {"type": type(value).__qualname__, **{k: canonical(v) for k, v in sorted(vars(value).items())}}
    raise TypeError(f"cannot fingerprint a {type(value).__qualname__}")


def _fields(value: Any) -> dict[str, Any]:
    return {"type": type(value).__qualname__,
            **{f.name: canonical(getattr(value, f.name)) for f in dataclasses.fields(value)}}


def fingerprint(task: FitTask) -> dict[str, str]:
    """One hash per input of the task (its folder aside: a moved folder
    keeps its fits), and the function's name."""
    parts = {"function": canonical(task.function),
             **{k: canonical(v) for k, v in task.kwargs.items() if k != FOLDER_KEYWORD}}
    return {k: _sha(json.dumps(v, sort_keys=True).encode()) for k, v in parts.items()}


def write_json(path: Path, value: Any) -> None:
    """Write ``path`` whole or not at all: a temporary file, flushed, renamed over it."""
    path.parent.mkdir(parents=True, exist_ok=True)
    temporary = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    with temporary.open("w") as handle:
        json.dump(value, handle, indent=1)
        handle.flush()
        os.fsync(handle.fileno())
    os.replace(temporary, path)


def run_and_record(function: Callable[..., Any], kwargs: dict[str, Any], folder: str | Path,
                   fingerprint: dict[str, str], keep: Callable[[Any], Any]) -> Any:
    """Run one fit (where the fit runs), then record it as finished: last,
    after the fit's own files."""
    value = function(**kwargs)
    write_json(Path(folder) / RECORD, {"fingerprint": fingerprint, "kept": keep(value)})
    return value


def keep_nothing(value: Any) -> None:
    """For fits whose files hold all of their value."""
    return None


def keep_whole(value: Any) -> Any:
    """For fits whose value is small JSON (SBC's ranks)."""
    return value


def _said(names: list[str]) -> str:
    shown = ", ".join(names[:NAMES_SAID])
    return shown + (f" and {len(names) - NAMES_SAID} more" if len(names) > NAMES_SAID else "")


class Resume:
    """A command's resumption in its output folder (None: nothing is
    resumed): the seed, and runner.map that reuses finished fits."""

    def __init__(self, out_dir: str | Path | None, seed: int | None) -> None:
        self.out = None if out_dir is None else Path(out_dir)
        kept = self.out / SEED_RECORD if self.out is not None else None
        if seed is None and kept is not None and kept.is_file():
            seed = json.loads(kept.read_text())["seed"]
        self.seed = command_seed(seed)

    def map(self, runner: FitRunner, tasks: list[FitTask], *, keep: Callable[[Any], Any] = keep_nothing,
            restore: Callable[[FitTask, Path, Any], Any]) -> list[Any]:
        """runner.map(tasks), reusing each task's fit finished in its folder
        (its ``out_dir``) with the same fingerprint. ``keep`` (a module-level
        function: it runs where the fit runs) gives what the record keeps of
        a fit's value; ``restore(task, folder, kept)`` gives the value back."""
        if self.out is not None:
            write_json(self.out / SEED_RECORD, {"seed": self.seed})
        values: list[Any] = [None] * len(tasks)
        todo: list[tuple[int, FitTask]] = []
        changed: list[str] = []
        for index, task in enumerate(tasks):
            folder = task.kwargs.get(FOLDER_KEYWORD)
            if folder is None:
                todo.append((index, task))
                continue
            prints = fingerprint(task)
            found, reused = self._finished(task, Path(folder), prints, restore, changed)
            if found:
                values[index] = reused
            else:
                todo.append((index, FitTask(task.name, run_and_record, {
                    "function": task.function, "kwargs": task.kwargs, "folder": folder, "fingerprint": prints,
                    "keep": keep})))
        if changed:
            logger.info("fitting again what changed since it was written: %s", _said(changed))
        if len(todo) < len(tasks):
            logger.info("reused %d of %d fits finished earlier in %s", len(tasks) - len(todo), len(tasks), self.out)
        for (index, _), value in zip(todo, runner.map([task for _, task in todo]), strict=True):
            values[index] = value
        return values

    @staticmethod
    def _finished(task: FitTask, folder: Path, prints: dict[str, str], restore, changed: list[str]) -> tuple[bool, Any]:
        """(True, its value) for a fit finished with these inputs, else
        (False, None), its stale record removed (a rerun stopped before it
        finishes must not leave the old record beside new files)."""
        record = folder / RECORD
        if not record.is_file():
            return False, None
        try:
            written = json.loads(record.read_text())
        except ValueError:  # not stancal's: records are written whole
            written = {"fingerprint": {}}
        if written["fingerprint"] == prints:
            try:
                return True, restore(task, folder, written["kept"])
            except Exception as err:  # its files were removed or damaged since: whatever the reader raises
                reason = (str(err).strip().splitlines() or [type(err).__name__])[0]
                changed.append(f"{task.name} (its files cannot be read: {reason})")
        else:
            inputs = sorted({*prints, *written["fingerprint"]} - {
                k for k in prints if written["fingerprint"].get(k) == prints[k]})
            changed.append(f"{task.name} ({', '.join(inputs)})")
        record.unlink()
        return False, None
