"""A fit's log density and pointwise values at many unconstrained draws,
evaluated in worker processes side by side.

Moment matching (stancal.diagnosing.moment_match; Paananen, Piironen,
Bürkner & Vehtari 2021, *Statistics and Computing* 31, 16) passes every
draw through the model's log density and its write_array once for each
affine map it tries. Through httpstan each is one call per draw that builds
the model from the data again: on the counts case (90 points, 99
unconstrained dimensions) 2.3 ms for the log density and 2.5 ms for the
pointwise values, about 5 s per map over 1,000 draws, and a point tries
several maps. The draws are independent, so they are split over processes,
each of which builds the model once; not over threads, since the log
density's autodiff crashed Dask workers' threads
(pystan_backend.in_worker_thread). With one core, or one worker, everything
runs in this process as before.
"""

from __future__ import annotations

import multiprocessing
import os
import sys
from collections.abc import Callable, Iterator
from concurrent.futures import ProcessPoolExecutor, wait
from contextlib import contextmanager
from typing import Any

import numpy as np

from stancal.stan.backends import get_backend
from stancal.stan.backends.base import child_process_started
from stancal.stan.source import FlatProgram

# fewer draws than this per worker: the processes' round trip costs more than it saves
LEAST_DRAWS_PER_WORKER = 50

_IN_WORKER: dict[str, tuple[Callable, Callable]] = {}  # a worker's model functions, built once per fit


def _functions(key: str, backend: str | None, program: FlatProgram,
               stan_data: dict[str, Any]) -> tuple[Callable, Callable]:
    """This worker's log density and pointwise values of the fit ``key``,
    built at its first call (the compile is in the shared store); the fits
    are matched one after another, so only the latest is kept."""
    if key not in _IN_WORKER:
        _IN_WORKER.clear()
        stan_backend = get_backend(backend)
        _IN_WORKER[key] = (stan_backend.log_density_functions(program, stan_data)[1],
                           stan_backend.unconstrained_quantities_function(program, stan_data))
    return _IN_WORKER[key]


def _log_density(spec: tuple, points: np.ndarray) -> np.ndarray:
    return _functions(*spec)[0](points)


def _quantities(spec: tuple, names: tuple[str, ...], points: np.ndarray) -> dict[str, np.ndarray]:
    values = _functions(*spec)[1](points)
    return {name: np.asarray(values[name]) for name in names}


def default_workers() -> int:
    """The processes moment matching uses: the cores this process may run on
    (a batch system's or a container's share, not the host's)."""
    return len(os.sched_getaffinity(0))


@contextmanager
def _main_hidden() -> Iterator[None]:
    """The command's __main__ without a file or module name while workers
    start: a spawned process runs the parent's main script again (as
    __mp_main__) to find its functions, and a user's script without an
    ``if __name__ == "__main__"`` guard would then run its gap diagnosis
    again in every worker. The workers need only this module's functions."""
    main = sys.modules["__main__"]
    saved = {name: main.__dict__.pop(name) for name in ("__file__", "__spec__") if name in main.__dict__}
    main.__spec__ = None
    try:
        yield
    finally:
        main.__dict__.pop("__spec__", None)
        main.__dict__.update(saved)


class DensityPool:
    """Worker processes that evaluate fits' log densities and pointwise
    values at many draws, split between them (spawned: a fork would copy the
    command's threads, Dask's among them). Used as a context manager; with
    ``workers`` at most 1 it starts nothing and every function runs here."""

    def __init__(self, workers: int | None = None):
        self.workers = default_workers() if workers is None else workers
        self._pool: ProcessPoolExecutor | None = None
        self._fits = 0

    def __enter__(self) -> DensityPool:
        # a daemonic process (a stock Dask worker, its nanny's child) may not start processes
        if self.workers > 1 and not multiprocessing.current_process().daemon:
            self._pool = ProcessPoolExecutor(self.workers, mp_context=multiprocessing.get_context("spawn"),
                                             initializer=child_process_started, initargs=(os.getpid(),))
            try:
                with _main_hidden():  # every worker starts now, while the user's script is out of sight
                    for started in wait([self._pool.submit(os.getpid) for _ in range(self.workers)]).done:
                        started.result()  # a worker that failed to start says so here
            except BaseException:
                self.__exit__()
                raise
        return self

    def __exit__(self, *exc: object) -> None:
        if self._pool is not None:
            self._pool.shutdown(cancel_futures=True)
            self._pool = None

    def functions(self, backend: str | None, program: FlatProgram, stan_data: dict[str, Any],
                  names: tuple[str, ...]) -> tuple[Callable, Callable] | None:
        """A fit's (log density, pointwise ``names``) at points (n, d), run in
        the workers; None without workers (the caller's own functions serve)."""
        if self._pool is None:
            return None
        self._fits += 1
        spec = (f"fit {self._fits}", backend, program, stan_data)
        pool = self._pool

        def chunks(points: np.ndarray) -> list[np.ndarray]:
            return np.array_split(points, max(1, min(self.workers, len(points) // LEAST_DRAWS_PER_WORKER)))

        def log_density(points: np.ndarray) -> np.ndarray:
            parts = chunks(points)
            return np.concatenate(list(pool.map(_log_density, [spec] * len(parts), parts)))

        def quantities(points: np.ndarray) -> dict[str, np.ndarray]:
            parts = chunks(points)
            done = list(pool.map(_quantities, [spec] * len(parts), [names] * len(parts), parts))
            return {name: np.concatenate([part[name] for part in done]) for name in names}

        return log_density, quantities
