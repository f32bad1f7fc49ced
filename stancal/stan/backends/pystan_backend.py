"""PyStan 3 (httpstan): the embedded backend that needs only pip and g++."""

from __future__ import annotations

import contextlib
import functools
import json
import logging
import multiprocessing
import os
import subprocess
import tempfile
import time
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

from stancal.numerics.laplace import laplace_log_mass
from stancal.stan.backends.base import (
    SAMPLER_STATS,
    Draws,
    SampleOutput,
    StanRuntimeError,
    WarmStart,
    child_process_started,
    fresh_prediction_normals,
    warm_windows,
)
from stancal.stan.backends.pystan_compile import (
    STANC_TIMEOUT_S,
    compile_programs,
    held_output,
    program_file,
    stanc,
    stanc_binary,
    stored_module,
)
from stancal.stan.progress import progress_lines, sampling_progress
from stancal.stan.source import FlatProgram, StanProgramError

logger = logging.getLogger("stancal")


def _draw(parameters: Draws, chain: int, draw: int) -> dict[str, Any]:
    """One parameter draw as the lists the services functions take."""
    return {k: np.asarray(v[chain, draw]).tolist() for k, v in parameters.items()}


def _by_chain(flat: np.ndarray, dims: list[int], chains: int) -> np.ndarray:
    """PyStan's (*dims, draw * chains) with chain varying fastest -> (chain, draw, *dims)."""
    draws = flat.shape[-1] // chains
    return np.moveaxis(flat.reshape(*dims, draws, chains), [-1, -2], [0, 1])


def _by_variable(flat: np.ndarray, model, leading: tuple[int, ...], count: int | None = None) -> Draws:
    """Rows of write_array's output (every variable, flattened column-major as
    Stan does; or its first ``count`` variables, the parameters, where it was
    asked for those alone) -> variable name -> (*leading, *its shape)."""
    out: Draws = {}
    offset = 0
    for name, shape in list(zip(model.param_names, model.dims, strict=True))[:count]:
        size = int(np.prod(shape))
        block = flat[:, offset : offset + size].reshape(*leading, *reversed(shape))
        n = len(leading)
        out[name] = block.transpose(*range(n), *range(block.ndim - 1, n - 1, -1))  # the variable's axes in order
        offset += size
    return out


def _by_variable_first(flat: np.ndarray, model, count: int) -> dict[str, Any]:
    """One row of write_array's parameters alone (its first ``count``
    variables) -> name -> nested lists, as transform_inits takes them."""
    return {name: value[0].tolist() for name, value in _by_variable(flat[:1], model, (1,), count).items()}


def _interior_point(model) -> dict[str, Any]:
    """0.1 for every variable: inside every constraint stancal's programs use,
    the Hilbert-space programs' upper bounds on length scales (0.19 at the
    least) among them (transform_inits reads the parameters and ignores the rest)."""
    return {name: np.full(dims, 0.1).tolist() for name, dims in zip(model.param_names, model.dims, strict=True)}


_chain_pool: ProcessPoolExecutor | None = None


def _chains_in_processes_that_end_with_this_one() -> None:
    """httpstan samples each chain in a process forked from this one (its
    services_stub.executor; a chain run in a thread of this process instead
    crashed it, a segmentation fault with httpstan 4.17). Its processes outlive
    this one when it is killed, and multiprocessing refuses them to a
    daemonic process, such as a stock Dask worker (started by its nanny),
    for that reason. The pool put in its place here is the same (forked, as
    many at a time), so the draws are the same, but each of its processes
    ends when this one does (end_when_orphaned), which is what the rule
    protects: so a daemonic process may start them."""
    global _chain_pool
    import httpstan.services_stub

    process = multiprocessing.current_process()
    if process.daemon:
        process.daemon = False
    if _chain_pool is None or httpstan.services_stub.executor is not _chain_pool:
        _chain_pool = ProcessPoolExecutor(mp_context=multiprocessing.get_context("fork"),
                                          initializer=child_process_started, initargs=(os.getpid(),))
        httpstan.services_stub.executor = _chain_pool


@contextlib.contextmanager
def _sampling_output(model_name: str, label: str, total: int):
    """PyStan's sampling output, tamed. Its progress lines drive stancal's
    progress (stancal.stan.progress: a bar on a terminal, a compact log
    elsewhere); Stan's informational messages and what else it prints are
    held back (shown if sampling fails). httpstan keeps every seeded fit's draws in
    its cache, gigabytes over time, and would serve the same draws again for
    the same seed and data: the fits made here are deleted once read."""
    import httpstan.cache

    fits = httpstan.cache.model_directory(model_name) / "fits"
    before = set(fits.glob("*")) if fits.is_dir() else set()
    try:
        with sampling_progress(label, total) as progress, held_output(descriptors=False), progress_lines(progress):
            yield
    finally:
        for path in (set(fits.glob("*")) if fits.is_dir() else set()) - before:
            path.unlink(missing_ok=True)


@functools.cache
def _program_info(code: str) -> dict[str, Any]:
    """stanc's --info on a program: its variables by block."""
    with tempfile.TemporaryDirectory(prefix="stancal_") as folder:
        path = Path(folder) / "program.stan"
        path.write_text(code)
        done = subprocess.run([str(stanc_binary()), "--info", str(path)], capture_output=True, text=True,
                              timeout=STANC_TIMEOUT_S)
    if done.returncode != 0:
        raise StanProgramError(done.stderr.strip())
    return json.loads(done.stdout)


def in_worker_thread() -> bool:
    """Not the process's main thread (a Dask worker's): httpstan's model
    services called there crashed stock workers (signal 11, httpstan 4.17)."""
    import threading

    return threading.current_thread() is not threading.main_thread()


class PyStanBackend:
    name = "pystan"

    def _build(self, program: FlatProgram, data: dict[str, Any], seed: int):
        import stan

        # compiled here rather than by stan.build, whose HTTP request to httpstan
        # times out after 5 minutes: a compile can take longer on a busy 2-core machine
        self.compile([program])  # into this process's own httpstan cache (compile_programs)
        try:
            with held_output():
                return stan.build(program.code, data=data, random_seed=seed)
        except ValueError as err:  # stanc errors and data errors arrive as ValueError
            raise StanProgramError(program.explain(str(err))) from None
        except RuntimeError as err:
            raise StanRuntimeError(program.explain(str(err))) from None

    def compile(self, programs: list[FlatProgram]) -> float:
        for program in {p.code: p for p in programs if not stored_module(p.code).is_file()}.values():
            self.check(program, show_warnings=True)  # stanc's errors first, with the user's lines
        return compile_programs(programs)

    @staticmethod
    def check(program: FlatProgram, show_warnings: bool = False) -> None:
        """Run stanc alone (no C++, a fraction of a second). PyStan's build
        error keeps only 'Semantic error'; stanc gives the whole message.
        ``show_warnings``: log stanc's warnings, with the user's file and line."""
        try:
            _, warnings = stanc(program.code, "stancal_check")
        except ValueError as err:
            raise StanProgramError(program.explain(str(err))) from None
        if show_warnings:
            for warning in program.users_warnings(warnings):
                logger.warning("stanc: %s", warning)

    def parameter_names(self, program: FlatProgram) -> list[str]:
        return list(_program_info(program.code)["parameters"])

    def parameter_shapes(self, program: FlatProgram, data: dict[str, Any]) -> dict[str, tuple[int, ...]]:
        model = self._build(program, data, seed=1)
        shapes = dict(zip(model.param_names, model.dims, strict=True))  # every variable of the program
        return {name: tuple(shapes[name]) for name in self.parameter_names(program)}

    def start_error(self, program: FlatProgram, data: dict[str, Any],
                    inits: list[dict[str, Any]] | None) -> str | None:
        """In this process, through the compiled model's services module:
        no HTTP round trip and none of httpstan's log lines."""
        import httpstan.models

        if in_worker_thread():
            # a Dask worker's thread: this call before sampling crashed stock workers (signal 11,
            # httpstan 4.17, tests/test_cluster.py); there the sampler's own failure is explained
            # instead (stancal.fitting.simulator_check.explained)
            return None
        model = self._build(program, data, seed=1)
        services = httpstan.models.import_services_extension_module(model.model_name)
        point = _interior_point(model)
        point.update(inits[0] if inits else {})
        try:
            services.log_prob(model.data, services.transform_inits(model.data, point), True)
        except (RuntimeError, ValueError) as err:  # Stan's domain errors arrive as ValueError
            return program.explain(str(err))
        return None

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
        started = time.perf_counter()
        model = self._build(program, data, seed)
        compiled = time.perf_counter()
        kwargs: dict[str, Any] = {
            "num_chains": chains, "num_warmup": warmup, "num_samples": draws,
            "delta": adapt_delta, "max_depth": max_treedepth, **self._warm(warm_start, warmup),
        }
        inits = warm_start.inits if warm_start is not None else inits
        if inits is not None:
            kwargs["init"] = inits
        _chains_in_processes_that_end_with_this_one()
        try:
            with _sampling_output(model.model_name, f"sampling {program_file(program)}", chains * (warmup + draws)):
                fit = model.sample(**kwargs)
        except RuntimeError as err:
            raise StanRuntimeError(self._explain_failure(model, program, inits, err)) from None
        finished = time.perf_counter()
        logger.info("sampled in %.0f s", finished - compiled)
        names = list(fit.param_names)
        draws_out = {
            n: _by_chain(np.asarray(fit[n]), list(fit.dims[i]), chains)
            for i, n in enumerate(names)
        }
        stats = {
            out: _by_chain(np.asarray(fit[stan_name]).reshape(-1), [], chains)
            for stan_name, out in SAMPLER_STATS.items()
            if stan_name in fit.sample_and_sampler_param_names
        }
        return SampleOutput(
            draws=draws_out,
            sample_stats=stats,
            max_treedepth=max_treedepth,
            load_seconds=compiled - started,
            sample_seconds=finished - compiled,
        )

    @staticmethod
    def _warm(warm_start: WarmStart | None, warmup: int) -> dict[str, Any]:
        """httpstan's sampler arguments for a warm start: the step size and
        the adaptation windows. Its services take no inverse metric
        (hmc_nuts_diag_e_adapt_wrapper in httpstan's stan_services.cpp), so
        the metric starts at the identity and is adapted again in the window."""
        if warm_start is None:
            return {}
        return {"stepsize": float(warm_start.step_size), **warm_windows(warmup)}

    @staticmethod
    def _explain_failure(model, program: FlatProgram, inits, err: RuntimeError) -> str:
        """httpstan 4.17 can lose Stan's message while reporting a failed run;
        evaluating the log density at the first init usually recovers it."""
        message = str(err)
        if inits:
            point = _interior_point(model)  # for the variables the init leaves to Stan
            point.update(inits[0])
            try:
                model.log_prob(model.unconstrain_pars(point))
            except Exception as inner:  # the recovered Stan message
                message = f"{inner}"
        return program.explain(f"Stan failed while sampling: {message.strip()}")

    def generate_quantities(
        self, program: FlatProgram, data: dict[str, Any], parameters: Draws, seed: int
    ) -> Draws:
        return self.quantities_function(program, data, seed)(parameters)

    def quantities_function(self, program: FlatProgram, data: dict[str, Any],
                            seed: int) -> Callable[[Draws], Draws]:
        """Build once, then run generated quantities for any parameter draws
        (chain, draw, ...) in this process: PyStan's constrain_pars makes two
        HTTP round trips per draw. httpstan seeds the RNG of every call with 0,
        so the draws at the prediction points take their standard normals from
        the data, fresh for every parameter draw (fresh_prediction_normals)."""
        import httpstan.models

        model = self._build(program, data, seed)
        services = httpstan.models.import_services_extension_module(model.model_name)
        rng = np.random.default_rng(seed)

        def run(parameters: Draws) -> Draws:
            chains, draws = next(iter(parameters.values())).shape[:2]
            flat_rows = []
            try:
                for c in range(chains):
                    for d in range(draws):
                        unconstrained = services.transform_inits(model.data, _draw(parameters, c, d))
                        draw_data = {**model.data, **fresh_prediction_normals(model.data, rng)}
                        flat_rows.append(services.write_array(draw_data, unconstrained, True, True))
            except RuntimeError as err:
                raise StanRuntimeError(program.explain(f"Stan failed in generated quantities: {err}")) from None
            values = _by_variable(np.asarray(flat_rows, dtype=float), model, (chains, draws))
            return {name: v for name, v in values.items() if name not in parameters}

        return run

    def _optimiser(self, program: FlatProgram, data: dict[str, Any], seed: int):
        """The compiled model's services, its unconstrained dimension, L-BFGS
        on its negative log density (with the Jacobian, as lp__) from one
        unconstrained point (a point outside the support counts as +inf), and
        the log density's gradient (NaN outside the support)."""
        import httpstan.models
        from scipy.optimize import minimize

        model = self._build(program, data, seed)
        services = httpstan.models.import_services_extension_module(model.model_name)
        dimension = len(services.transform_inits(model.data, _interior_point(model)))

        def gradient(point: np.ndarray) -> np.ndarray:
            try:
                return np.asarray(services.log_prob_grad(model.data, point.tolist(), True))
            except (RuntimeError, ValueError):  # outside the support (Stan's domain errors arrive as ValueError)
                return np.full(dimension, np.nan)

        def negative_log_density(point: np.ndarray) -> tuple[float, np.ndarray]:
            try:
                lp = services.log_prob(model.data, point.tolist(), True)
            except (RuntimeError, ValueError):
                return np.inf, np.zeros(dimension)
            slope = gradient(point)
            return (-lp, -slope) if np.all(np.isfinite(slope)) else (np.inf, np.zeros(dimension))

        def run(start: np.ndarray):
            return minimize(negative_log_density, start, jac=True, method="L-BFGS-B")

        return model, services, dimension, run, gradient

    def posterior_mode(self, program: FlatProgram, data: dict[str, Any], *, starts: int,
                       seed: int) -> tuple[Draws, float]:
        model, services, dimension, run, _ = self._optimiser(program, data, seed)
        rng = np.random.default_rng(seed)
        runs = [run(rng.uniform(-2, 2, dimension)) for _ in range(starts)]  # Stan's default inits: uniform(-2, 2)
        best = min(runs, key=lambda run: run.fun)
        if not np.isfinite(best.fun):
            raise StanRuntimeError(program.explain(
                f"no finite log density found from {starts} starting points: {best.message}"))
        at_mode = services.write_array(model.data, best.x.tolist(), True, True)
        return _by_variable(np.asarray([at_mode], dtype=float), model, (1, 1)), -float(best.fun)

    def optima(self, program: FlatProgram, data: dict[str, Any], *, starts: list[dict[str, Any]],
               seed: int) -> list[tuple[Draws, float, float]]:
        model, services, dimension, run, gradient = self._optimiser(program, data, seed)

        count = len(self.parameter_names(program))  # write_array gives the parameters first, in order
        rng = np.random.default_rng(seed)
        out = []
        for start in starts:
            # Stan's random init for what the start leaves out, then the start's values in place
            values = services.write_array(model.data, rng.uniform(-2, 2, dimension).tolist(), False, False)
            point = _by_variable_first(np.asarray([values], dtype=float), model, count)
            point.update(start)
            found = run(np.asarray(services.transform_inits(model.data, point), dtype=float))
            try:
                at = services.write_array(model.data, found.x.tolist(), True, True)
            except (RuntimeError, ValueError):  # a rejection in transformed parameters or generated quantities
                out.append(({}, -np.inf, -np.inf))
                continue
            out.append((_by_variable(np.asarray([at], dtype=float), model, (1, 1)), -float(found.fun),
                        laplace_log_mass(-float(found.fun), gradient, found.x)))
        return out

    def log_density_functions(self, program: FlatProgram, data: dict[str, Any]):
        import httpstan.models

        model = self._build(program, data, seed=1)
        services = httpstan.models.import_services_extension_module(model.model_name)

        def unconstrain(parameters: Draws) -> np.ndarray:
            chains, draws = next(iter(parameters.values())).shape[:2]
            return np.asarray([[services.transform_inits(model.data, _draw(parameters, c, d))
                                for d in range(draws)] for c in range(chains)], dtype=float)

        def log_density(points: np.ndarray) -> np.ndarray:
            out = np.empty(len(points))
            for i, point in enumerate(points):
                try:
                    out[i] = services.log_prob(model.data, point.tolist(), True)
                except (RuntimeError, ValueError):  # outside the support, a domain error, a rejected simulator
                    out[i] = -np.inf
            return out

        return unconstrain, log_density

    def unconstrained_quantities_function(self, program: FlatProgram,
                                          data: dict[str, Any]) -> Callable[[np.ndarray], Draws]:
        """Build once, then every variable of the program (generated quantities
        among them) at unconstrained points (n, d), through the compiled
        model's write_array in this process; a point where Stan fails (outside
        the support, a rejected simulator) gives NaN. httpstan's write_array
        builds the model from the data at each call: give it data without
        prediction points (P = 0) where they are not needed."""
        import httpstan.models

        if in_worker_thread():  # the model's log density there crashed the process (start_error)
            raise NotImplementedError("the model's log density runs only in a process's main thread here")
        model = self._build(program, data, seed=1)
        services = httpstan.models.import_services_extension_module(model.model_name)
        width = sum(int(np.prod(shape)) for shape in model.dims)

        def at(point: np.ndarray) -> list[float]:
            try:
                return services.write_array(model.data, point.tolist(), True, True)
            except (RuntimeError, ValueError):  # Stan's exceptions, domain errors among them
                return [np.nan] * width

        def run(points: np.ndarray) -> Draws:
            flat = np.asarray([at(point) for point in points], dtype=float).reshape(len(points), width)
            return _by_variable(flat, model, (len(points),))

        return run
