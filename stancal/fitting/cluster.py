"""Many independent fits at once, on Dask (dask.distributed).

A command that makes many fits (a gap diagnosis, compare, SBC) hands them
to a FitRunner as FitTasks. The runner sends them to

- by default, a local cluster that it starts and stops: one single-threaded
  worker process per core (each fit runs its chains in processes of its own),
  started as fresh processes (distributed's SubprocessCluster), so that a
  user's script needs no ``if __name__ == "__main__"`` guard. Its scheduler
  and workers end themselves when the command is gone (killed, even by
  SIGKILL): nothing keeps sampling or writing into its output;
- ``scheduler="tcp://host:8786"``: an existing cluster, started as people
  start one (``dask scheduler`` and ``dask worker``, or dask-jobqueue on
  SLURM/PBS), with no special setting: daemonic workers with a nanny are fine
  (the backend's chain processes end with their worker), and so are workers
  with several threads (a worker process runs one fit at a time);
- ``scheduler="in-process"``: this process, one fit after another, no Dask.

Every task carries its own seed (seeds.fit_seed), so the results are the same
whatever runs them. A task that raises is retried once (Dask's ``retries``),
then reported as a FitFailure that names it while the others finish; a
worker lost mid-run has its tasks rerun elsewhere by the scheduler. Each
worker installs the Stan programs once from its machine's store, which
builds each at most once per machine (backends.pystan_compile).
"""

from __future__ import annotations

import logging
import os
import shutil
import sys
import tempfile
import threading
import time
import uuid
import warnings
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import click

from stancal.problem import advice
from stancal.stan import progress as stan_progress
from stancal.stan.backends import get_backend
from stancal.stan.backends.base import end_children, end_when_orphaned
from stancal.stan.source import FlatProgram

logger = logging.getLogger("stancal")

IN_PROCESS = "in-process"
TASK_PREFIX = "stancal-fit"  # the dashboard groups the tasks under it
RETRIES = 1


@dataclass(frozen=True)
class FitTask:
    """One fit: ``function(**kwargs)``, a module-level function (it is sent to
    the workers by reference). ``name`` is said in progress and failures."""

    name: str
    function: Callable[..., Any]
    kwargs: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class FitFailure:
    """A task that failed twice."""

    name: str
    error: str

    def __str__(self) -> str:
        return f"{self.name} failed: {self.error}"


# A fit holds its process's output (file descriptors 1 and 2, while it samples), its
# warning filters (_captured) and httpstan's cache of fits (cleared of the fits that
# appeared while it sampled): two at once in one process would spoil each other's.
# A worker with several threads (`dask worker`'s default) runs its fits one after another.
_one_fit_at_a_time = threading.RLock()  # re-entrant: a fit may run fits of its own in-process


def _captured(function: Callable[..., Any], kwargs: dict[str, Any],
              reader: str = advice.PYTHON) -> tuple[Any, list[tuple[str, type[Warning], str, int]]]:
    """Run one task, keeping its warnings (sampler trouble, ...) to say them
    where the command runs, not in a worker's log; their advice is for
    ``reader``, the command's (stancal.problem.advice). It shows no progress
    of its own: the runner shows the fits done."""
    with _one_fit_at_a_time, advice.spoken_to(reader), stan_progress.quiet(), \
            warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        value = function(**kwargs)
    return value, [(str(w.message), w.category, w.filename, w.lineno) for w in caught]


_PACKAGE = str(Path(__file__).resolve().parents[1])


def _pass_on(fit: str, message: str, category: type[Warning], filename: str, lineno: int) -> None:
    """Say a fit's warning where the command runs. stancal's own name the fit
    they came from; another library's (a deprecation inside PyStan's
    dependencies, say) are replayed as raised, so that the filters that hide
    them outside a fit hide them here too."""
    if str(Path(filename).resolve()).startswith(_PACKAGE):
        warnings.warn(f"{fit}: {message}", category, stacklevel=3)
    else:
        warnings.warn_explicit(message, category, filename, lineno)


def _describe(error: BaseException) -> str:
    lines = [line for line in str(error).strip().splitlines() if line.strip()]
    return f"{type(error).__name__}: {lines[-1] if lines else ''}".rstrip(": ")


def _prepare_worker(programs: list[FlatProgram], backend: str | None) -> None:
    """On each worker: install the programs (from the machine's store,
    where they are built once)."""
    get_backend(backend).compile(programs)


@click.command()
@click.option("--scratch", required=True, help="the command's scratch folder")
def dask_setup(server, scratch: str) -> None:
    """Preloaded by the local cluster's scheduler and workers (distributed's
    ``preload``): each ends when the command that started it is gone, as a
    killed command cannot stop them itself, and removes the command's
    scratch folder (the workers' httpstan caches), as it cannot either."""
    end_when_orphaned(os.getppid(), clean_up=lambda: remove_scratch(scratch))


def remove_scratch(scratch: str | Path) -> None:
    """Remove the command's scratch folder, from a process of its cluster:
    after this process's own chains have ended, as they write into it until
    they notice this process's end (removed under them, it was left behind).
    Every process of the cluster removes it; the last one leaves nothing."""
    end_children()
    shutil.rmtree(scratch, ignore_errors=True)


def _private_cache_plugin(scratch: Path | None):
    """A worker plugin that gives each worker process a httpstan cache of
    its own (pystan_compile.use_private_httpstan_cache), under ``scratch``
    (else the temporary folder), and removes it when the worker stops.
    Registered with the scheduler, so that workers that join later (a
    restarted one) get it too."""
    from distributed import WorkerPlugin

    class PrivateHttpstanCache(WorkerPlugin):
        name = "stancal-private-httpstan-cache"

        def setup(self, worker) -> None:
            from stancal.stan.backends.pystan_compile import use_private_httpstan_cache

            self.folder = Path(tempfile.mkdtemp(prefix="stancal-httpstan-", dir=scratch))
            use_private_httpstan_cache(self.folder)

        def teardown(self, worker) -> None:
            from stancal.stan.backends.pystan_compile import release_private_httpstan_cache

            release_private_httpstan_cache(self.folder)

    return PrivateHttpstanCache()


class _Progress:
    """One bar for the command: fits done out of fits submitted so far."""

    def __init__(self, show: bool) -> None:
        self.show, self.done, self.total = show, 0, 0
        self.terminal = sys.stderr.isatty()

    def add(self, count: int) -> None:
        self.total += count
        self._draw(None)

    def finished(self, name: str, failed: bool = False) -> None:
        self.done += 1
        self._draw(f"{name} {'failed' if failed else 'done'}")

    def _draw(self, event: str | None) -> None:
        if not self.show or self.total == 0:
            return
        if self.terminal:
            filled = round(30 * self.done / self.total)
            sys.stderr.write(f"\rstancal: fits [{'#' * filled}{'.' * (30 - filled)}] {self.done}/{self.total}")
            if self.done == self.total:
                sys.stderr.write("\n")
            sys.stderr.flush()
        elif event:
            logger.info("fits %d/%d: %s", self.done, self.total, event)


class FitRunner:
    """Runs FitTasks on Dask (see the module's docstring); a context manager
    that starts and stops the local cluster it makes."""

    def __init__(self, scheduler: str | None = None, *, progress: bool = True, workers: int | None = None) -> None:
        self.scheduler = scheduler
        self.workers = workers or os.cpu_count() or 1
        self.progress = _Progress(progress)
        self.client = None
        self._cluster = None
        self._scratch: Path | None = None

    def __enter__(self) -> FitRunner:
        if self.scheduler == IN_PROCESS:
            return self
        from distributed import Client

        started = time.perf_counter()
        if self.scheduler is None:
            # workers as fresh `dask spec` processes, not multiprocessing children: these never
            # re-run the user's script (no __main__ guard needed)
            from stancal.fitting.local_cluster import local_cluster

            self._scratch = Path(tempfile.mkdtemp(prefix="stancal-cluster-"))
            ending = {"preload": [__name__], "preload_argv": ["--scratch", str(self._scratch)]}  # dask_setup
            self._cluster = local_cluster(self.workers, ending, {"memory_limit": 0, **ending})
            self.client = Client(self._cluster)
            self._wait_for_workers()
        else:
            self.client = Client(self.scheduler, timeout="30s")
        self.client.register_plugin(_private_cache_plugin(self._scratch))
        logger.info("Dask: %d workers (%s), dashboard %s; started in %.1f s",
                    len(self.client.scheduler_info()["workers"]),
                    "local cluster" if self._cluster else self.scheduler,
                    self.client.dashboard_link, time.perf_counter() - started)
        return self

    def _wait_for_workers(self) -> None:
        from stancal.fitting.local_cluster import START_TIMEOUT_S

        try:
            self.client.wait_for_workers(self.workers, timeout=START_TIMEOUT_S)
        except TimeoutError:
            self.__exit__()
            raise RuntimeError(f"{self.workers} Dask workers did not all start within {START_TIMEOUT_S:.0f} s "
                               "(is the machine overloaded?)") from None

    def __exit__(self, *exc) -> None:
        if self.client is not None:
            self.client.close()
        if self._cluster is not None:
            self._cluster.close()  # kills the workers: their private caches go with the scratch folder
            shutil.rmtree(self._scratch, ignore_errors=True)

    def prepare(self, programs: list[FlatProgram], backend: str | None = None) -> float:
        """Compile the programs here (stanc's errors point at the user's
        lines) and install them on every worker before any fit starts.
        Returns the seconds spent compiling (0.0: all compiled earlier)."""
        compile_s = get_backend(backend).compile(programs)
        if self.client is not None:
            self.client.run(_prepare_worker, programs, backend)
        return compile_s

    def map(self, tasks: list[FitTask]) -> list[Any]:
        """Each task's value, or its FitFailure, in the tasks' order."""
        self.progress.add(len(tasks))
        runs = self._in_cluster(tasks) if self.client is not None else self._here(tasks)
        values: list[Any] = [None] * len(tasks)
        for index, outcome in runs:
            if isinstance(outcome, FitFailure):
                logger.warning("%s", outcome)
                values[index] = outcome
            else:
                values[index], caught = outcome
                for caught_warning in caught:  # said once
                    _pass_on(tasks[index].name, *caught_warning)
            self.progress.finished(tasks[index].name, isinstance(outcome, FitFailure))
        return values

    def _here(self, tasks: list[FitTask]) -> Iterator[tuple[int, Any]]:
        for index, task in enumerate(tasks):
            for attempt in range(RETRIES + 1):
                try:
                    yield index, _captured(task.function, task.kwargs, advice.audience())
                    break
                except Exception as error:  # one failed fit must not lose the others
                    if attempt == RETRIES:
                        yield index, FitFailure(task.name, _describe(error))
                    else:
                        logger.warning("%s failed (%s); retrying once", task.name, _describe(error))

    def _in_cluster(self, tasks: list[FitTask]) -> Iterator[tuple[int, Any]]:
        from distributed import as_completed

        futures = {self.client.submit(_captured, task.function, task.kwargs, advice.audience(), pure=False,
                                      retries=RETRIES,
                                      key=f"{TASK_PREFIX}-{uuid.uuid4().hex}"): index
                   for index, task in enumerate(tasks)}
        for future in as_completed(list(futures)):
            index = futures[future]
            if future.status == "error":
                yield index, FitFailure(tasks[index].name, _describe(future.exception()))
            else:
                yield index, future.result()
            future.release()


@contextmanager
def fit_runner(scheduler: str | FitRunner | None = None, **options: Any) -> Iterator[FitRunner]:
    """A FitRunner for one command, or the caller's own (left running)."""
    if isinstance(scheduler, FitRunner):
        yield scheduler
        return
    with FitRunner(scheduler, **options) as runner:
        yield runner
