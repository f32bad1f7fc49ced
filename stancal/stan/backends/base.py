"""The one interface between stancal and a Stan interface library."""

from __future__ import annotations

import os
import signal
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np
import psutil

from stancal.stan.source import FlatProgram


def cache_root() -> Path:
    """Where every backend keeps what it builds: $STANCAL_CACHE, else
    stancal's folder in the user cache ($XDG_CACHE_HOME, else ~/.cache)."""
    if os.environ.get("STANCAL_CACHE"):
        return Path(os.environ["STANCAL_CACHE"])
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "stancal"


def child_process_started(parent: int) -> None:
    """A worker process of the command ``parent`` (a chain's, a density
    pool's): it leaves Ctrl-C to the command, as httpstan's do, and ends
    within a second of the command's end (end_when_orphaned)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    end_when_orphaned(parent)


def end_when_orphaned(parent: int, every: float = 0.5, clean_up: Callable[[], None] | None = None) -> None:
    """End this process within ``every`` seconds of its parent's end (the
    process ``parent``, which started it), after ``clean_up``. A process
    killed by a signal runs no clean-up, so what it started would otherwise
    keep sampling and writing (a chain's process, a local Dask cluster's
    scheduler and workers). A thread checks the parent: an orphan is handed
    to another one."""
    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(every)
        if clean_up is not None:
            clean_up()
        os._exit(1)  # nothing else: this process's work belongs to a command that is gone

    threading.Thread(target=watch, name="stancal-end-when-orphaned", daemon=True).start()


def end_children(wait: float = 5.0) -> None:
    """Kill this process's child processes (and theirs), and wait up to
    ``wait`` seconds for them to end; again while new ones appear (a thread
    may start a chain meanwhile), as a process about to end does with the
    work it started."""
    for _ in range(3):
        children = psutil.Process().children(recursive=True)
        if not children:
            return
        for child in children:
            try:
                child.kill()
            except psutil.NoSuchProcess:
                pass
        psutil.wait_procs(children, timeout=wait)


# Stan's sampler columns -> ArviZ sample_stats names
SAMPLER_STATS = {
    "lp__": "lp",
    "accept_stat__": "acceptance_rate",
    "stepsize__": "step_size",
    "treedepth__": "tree_depth",
    "n_leapfrog__": "n_steps",
    "divergent__": "diverging",
    "energy__": "energy",
}

Draws = dict[str, np.ndarray]
"""Variable name -> array of shape (chain, draw, *variable shape)."""


def fresh_prediction_normals(data: dict[str, Any], rng: np.random.Generator) -> dict[str, Any]:
    """Data entries that give a program fresh standard normals for its draws
    at the prediction points, for one parameter draw. A program opts in by
    declaring ``P_normals`` and ``normals_new`` (P x (2 + F), F = 0 when the
    program has no functional theta); see prediction_normals_rng in
    functions/gp_conditional.stan. The Hilbert-space programs draw their
    basis weights from ``B_normals`` and ``basis_normals`` (B, plus
    modular_hsgp's emulator-error weights) likewise; the programs with biased
    sources their bias curves from ``bias_normals_new`` (P x n_biased)."""
    out: dict[str, Any] = {}
    if "P_normals" in data:
        rows, columns = int(data["P"]), 2 + int(data.get("F", 0))
        out.update(P_normals=rows, normals_new=rng.standard_normal((rows, columns)).tolist())
        if "bias_normals_new" in data:  # biased sources' curves (functions/source_bias.stan)
            out.update(bias_normals_new=rng.standard_normal((rows, int(data["n_biased"]))).tolist())
    if "B_normals" in data:  # the Hilbert-space programs' basis weights (functions/hsgp.stan)
        weights = int(data["B"]) + int(data.get("emulator_error_rank", 0))
        out.update(B_normals=weights, basis_normals=rng.standard_normal(weights).tolist())
    return out


@dataclass(frozen=True)
class WarmStart:
    """Where a fit starts when an earlier fit of nearly the same model and
    data has ended: the gap diagnosis's refits without a few rows, and its
    candidates (the baseline plus one term). ``inits``: one point per chain
    (the program's parameters), drawn from the earlier posterior;
    ``step_size``: its adapted step size; ``inv_metric``: its adapted
    diagonal inverse metric on the unconstrained scale, one row per chain
    (None when the backend that made it does not report it). The sampler's
    warm-up, short then, keeps adapting from there (warm_windows): the
    posterior moves little when a few rows are held out or a term added."""

    inits: list[dict[str, Any]]
    step_size: float
    inv_metric: np.ndarray | None = None
    related: bool = False  # from another program (a candidate's start): fitted() to this one's shapes first

    def fitted(self, shapes: dict[str, tuple[int, ...]]) -> WarmStart:
        """This start for a program whose parameters have ``shapes``: an
        entry the program does not have, or has in another shape (a
        candidate's longer coefficient vector), is left to Stan's inits. The
        metric is kept only when every parameter of nonzero size starts from
        the earlier fit, with its shape (its length is then the same)."""
        inits = [{k: v for k, v in point.items() if k in shapes and np.shape(v) == tuple(shapes[k])}
                 for point in self.inits]
        sized = {k for k, shape in shapes.items() if int(np.prod(shape)) > 0}
        whole = all(sized <= set(point) for point in inits)
        return WarmStart(inits, self.step_size, self.inv_metric if whole else None, self.related)


def warm_windows(warmup: int) -> dict[str, int]:
    """Stan's adaptation windows for a warm-up that starts in the typical set:
    a short first buffer (no long way in to travel), one metric window, and
    Stan's usual final step-size buffer (as far as the warm-up allows).
    Stan's defaults (75, 25, 50) spend a 200-iteration warm-up's metric
    estimate on 25 draws; here it gets most of them."""
    init_buffer, term_buffer = max(warmup // 8, 5), min(50, max(warmup // 4, 5))
    return {"init_buffer": init_buffer, "term_buffer": term_buffer,
            "window": max(warmup - init_buffer - term_buffer, 1)}


class StanRuntimeError(RuntimeError):
    """Stan rejected the data or failed while sampling."""


@dataclass
class SampleOutput:
    draws: Draws
    sample_stats: Draws  # lp, diverging, tree_depth, n_steps, step_size, energy, ...
    max_treedepth: int
    load_seconds: float  # loading the compiled program with the data (compiling came before, in compile)
    sample_seconds: float
    messages: list[str] = field(default_factory=list)
    inv_metric: np.ndarray | None = None  # (chain, unconstrained dimension); None when the backend does not report it


class StanBackend(Protocol):
    name: str

    def check(self, program: FlatProgram) -> None:
        """Raise StanProgramError, with the user's file and line, if stanc rejects the program."""
        ...

    def compile(self, programs: list[FlatProgram]) -> float:
        """Compile the programs that are not compiled yet (each once, however
        often it is listed), in parallel over the machine's cores, so that the
        fits after it start at once. Returns the seconds spent compiling:
        0.0 when every program came from a cache (compiled earlier)."""
        ...

    def sample(
        self,
        program: FlatProgram,
        data: dict[str, Any],
        *,
        chains: int,
        warmup: int,
        draws: int,
        seed: int,
        inits: list[dict[str, Any]] | None,
        adapt_delta: float,
        max_treedepth: int,
        warm_start: WarmStart | None = None,
    ) -> SampleOutput:
        """NUTS with diagonal metric. ``warm_start``: start from an earlier
        fit's draws and adaptation (its ``inits`` replace ``inits``), and
        adapt in warm_windows(warmup)."""
        ...

    def parameter_names(self, program: FlatProgram) -> list[str]:
        """The names in the program's parameters block, read by stanc."""
        ...

    def parameter_shapes(self, program: FlatProgram, data: dict[str, Any]) -> dict[str, tuple[int, ...]]:
        """Each parameter's shape given the data (the data fix the sizes), in
        the parameters block's order: what generated quantities need, for
        draws stancal makes itself (stancal.fitting.confounding)."""
        ...

    def start_error(self, program: FlatProgram, data: dict[str, Any],
                    inits: list[dict[str, Any]] | None) -> str | None:
        """Stan's message (with the user's files and lines) if the log density
        fails at the first chain's start (its init, the other parameters
        inside their constraints), else None: a check before sampling, on
        the program already compiled."""
        ...

    def generate_quantities(
        self,
        program: FlatProgram,
        data: dict[str, Any],
        parameters: Draws,
        seed: int,
    ) -> Draws:
        """Rerun generated quantities for given parameter draws (chain, draw, ...),
        with fresh random numbers for every draw, seeded by ``seed``."""
        ...

    def quantities_function(
        self, program: FlatProgram, data: dict[str, Any], seed: int
    ) -> Callable[[Draws], Draws]:
        """generate_quantities with the program and data bound once, for many calls."""
        ...

    def posterior_mode(
        self, program: FlatProgram, data: dict[str, Any], *, starts: int, seed: int
    ) -> tuple[Draws, float]:
        """The posterior's mode on the unconstrained scale (the log density with
        its Jacobian, as lp__), the best of ``starts`` L-BFGS runs from Stan's
        random inits: every variable of the program there (parameters,
        transformed parameters, generated quantities) as one draw (1, 1, ...),
        and its lp."""
        ...

    def optima(
        self, program: FlatProgram, data: dict[str, Any], *, starts: list[dict[str, Any]], seed: int
    ) -> list[tuple[Draws, float, float]]:
        """One L-BFGS run on the unconstrained scale (the log density with its
        Jacobian, as lp__) from each start: a start gives some parameters'
        values (theta_unit, say), Stan's random inits give the rest. Per start,
        every variable of the program at the optimum it reached, as one draw
        (1, 1, ...), its lp (-inf where the run found no finite density), and
        the log of its mode's mass by the Laplace approximation
        (stancal.numerics.laplace; NaN where the backend cannot tell)."""
        ...

    def log_density_functions(
        self, program: FlatProgram, data: dict[str, Any]
    ) -> tuple[Callable[[Draws], np.ndarray], Callable[[np.ndarray], np.ndarray]]:
        """(unconstrain, log_density): parameter draws (chain, draw, ...) to
        unconstrained vectors (chain, draw, d), and the log density with its
        Jacobian (as the sampler's lp__) at unconstrained vectors (n, d)."""
        ...

    def unconstrained_quantities_function(
        self, program: FlatProgram, data: dict[str, Any]
    ) -> Callable[[np.ndarray], Draws]:
        """Every variable of the program (parameters, transformed parameters,
        generated quantities), each (n, ...), at unconstrained vectors (n, d):
        the pointwise log likelihood at moved draws (moment matching,
        stancal.diagnosing.moment_match). NaN where Stan fails at a point;
        NotImplementedError (its reason) where the backend cannot."""
        ...
