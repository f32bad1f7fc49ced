"""cmdstanpy: used when the user has a CmdStan installation."""

from __future__ import annotations

import logging
import os
import tempfile
import time
from itertools import product
from pathlib import Path
from typing import Any

import numpy as np

from stancal.stan.backends.base import (
    SAMPLER_STATS,
    Draws,
    SampleOutput,
    StanRuntimeError,
    WarmStart,
    cache_root,
    warm_windows,
)
from stancal.stan.source import FlatProgram, StanProgramError

logger = logging.getLogger("stancal")

def cmdstan_available() -> bool:
    try:
        import cmdstanpy

        cmdstanpy.cmdstan_path()
        return True
    except Exception:  # cmdstanpy raises ValueError or OSError when absent
        return False


def cache_dir() -> Path:
    return cache_root() / "cmdstan"


class CmdStanPyBackend:
    name = "cmdstanpy"

    def _model(self, program: FlatProgram):
        import cmdstanpy

        # keyed by the flat program's hash, so an edited include recompiles
        folder = cache_dir() / program.digest
        folder.mkdir(parents=True, exist_ok=True)
        stan_file = folder / "model.stan"
        if not stan_file.exists():
            stan_file.write_text(program.code)
        if not (folder / "model").exists():
            logger.warning("Compiling Stan program %s with CmdStan.", program.origin[0][0])
        try:
            return cmdstanpy.CmdStanModel(stan_file=str(stan_file))
        except (ValueError, RuntimeError) as err:
            raise StanProgramError(program.explain(str(err))) from None

    def check(self, program: FlatProgram) -> None:
        self._model(program)

    def compile(self, programs: list[FlatProgram]) -> float:
        # each compile is a make subprocess: threads are enough to run them side by side
        from concurrent.futures import ThreadPoolExecutor

        unique = {p.code: p for p in programs}.values()  # each program once
        building = any(not (cache_dir() / p.digest / "model").exists() for p in unique)
        started = time.perf_counter()
        with ThreadPoolExecutor(max_workers=os.cpu_count() or 1) as pool:
            list(pool.map(self._model, unique))
        return time.perf_counter() - started if building else 0.0

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
        model = self._model(program)
        compiled = time.perf_counter()
        try:
            fit = model.sample(
                data=data, chains=chains, parallel_chains=min(chains, os.cpu_count() or 1),
                iter_warmup=warmup, iter_sampling=draws, seed=seed,
                inits=inits if warm_start is None else warm_start.inits,
                adapt_delta=adapt_delta, max_treedepth=max_treedepth, show_progress=True,
                **self._warm(warm_start, warmup),
            )
        except RuntimeError as err:
            raise StanRuntimeError(program.explain(f"Stan failed while sampling: {err}")) from None
        finished = time.perf_counter()
        draws_out = {}
        for name, values in fit.stan_variables().items():
            values = np.asarray(values)
            draws_out[name] = values.reshape(chains, draws, *values.shape[1:])
        method = fit.method_variables()
        stats = {out: np.asarray(method[k]).T for k, out in SAMPLER_STATS.items() if k in method}
        return SampleOutput(
            draws=draws_out,
            sample_stats=stats,
            max_treedepth=max_treedepth,
            load_seconds=compiled - started,
            sample_seconds=finished - compiled,
            inv_metric=None if fit.metric is None else np.asarray(fit.metric),
        )

    @staticmethod
    def _warm(warm_start: WarmStart | None, warmup: int) -> dict[str, Any]:
        """CmdStan's arguments for a warm start besides its inits: the step
        size, the inverse metric (when the earlier fit reported one) and the
        adaptation windows."""
        if warm_start is None:
            return {}
        windows = warm_windows(warmup)
        out: dict[str, Any] = {"step_size": float(warm_start.step_size),
                               "adapt_init_phase": windows["init_buffer"],
                               "adapt_metric_window": windows["window"],
                               "adapt_step_size": windows["term_buffer"]}
        if warm_start.inv_metric is not None:
            out["metric"] = [{"inv_metric": row.tolist()} for row in np.atleast_2d(warm_start.inv_metric)]
        return out

    def parameter_names(self, program: FlatProgram) -> list[str]:
        return list(self._model(program).src_info()["parameters"])

    def parameter_shapes(self, program: FlatProgram, data: dict[str, Any]) -> dict[str, tuple[int, ...]]:
        # CmdStan reports the sizes only with values: one fixed-parameter iteration at its default inits
        fit = self._model(program).sample(data=data, fixed_param=True, chains=1, iter_warmup=0,
                                          iter_sampling=1, seed=1, show_progress=False)
        values = fit.stan_variables()
        # a parameter of size zero has no column, so no value
        return {name: np.shape(values[name])[1:] if name in values else (0,)
                for name in self.parameter_names(program)}

    def generate_quantities(
        self, program: FlatProgram, data: dict[str, Any], parameters: Draws, seed: int
    ) -> Draws:
        return self.quantities_function(program, data, seed)(parameters)

    def quantities_function(self, program: FlatProgram, data: dict[str, Any], seed: int):
        """CmdStan's standalone generated quantities on the given draws, written
        as Stan CSV files (a result loaded from netCDF has no fit CSVs). Its RNG
        runs on from draw to draw, so the prediction draws need no normals in
        the data."""
        model = self._model(program)

        def run(parameters: Draws) -> Draws:
            chains, draws = next(iter(parameters.values())).shape[:2]
            with tempfile.TemporaryDirectory(prefix="stancal_gq_") as folder:
                files = [write_stan_csv(Path(folder) / f"draws-{c + 1}.csv", parameters, c, seed)
                         for c in range(chains)]
                try:
                    quantities = model.generate_quantities(data=data, previous_fit=[str(f) for f in files],
                                                           seed=seed, gq_output_dir=folder)
                except RuntimeError as err:
                    raise StanRuntimeError(program.explain(f"Stan failed in generated quantities: {err}")) from None
                values = quantities.stan_variables()
            return {name: np.asarray(v).reshape(chains, draws, *np.asarray(v).shape[1:])
                    for name, v in values.items() if name not in parameters}

        return run

    def posterior_mode(self, program: FlatProgram, data: dict[str, Any], *, starts: int,
                       seed: int) -> tuple[Draws, float]:
        model = self._model(program)
        best = None
        for start in range(starts):
            try:
                fit = model.optimize(data=data, seed=seed + start, jacobian=True, algorithm="lbfgs")
            except RuntimeError as err:
                logger.info("optimisation from start %d failed: %s", start + 1, err)
                continue
            lp = float(fit.optimized_params_dict["lp__"])
            if best is None or lp > best[1]:
                best = ({name: np.asarray(v).reshape(1, 1, *np.shape(v)) for name, v in fit.stan_variables().items()},
                        lp)
        if best is None:
            raise StanRuntimeError(program.explain(f"optimisation failed from all {starts} starting points"))
        return best

    def optima(self, program: FlatProgram, data: dict[str, Any], *, starts: list[dict[str, Any]],
               seed: int) -> list[tuple[Draws, float, float]]:
        model = self._model(program)
        out: list[tuple[Draws, float, float]] = []
        for number, start in enumerate(starts):
            try:  # CmdStan fills what a partial init leaves out with its random inits
                fit = model.optimize(data=data, inits=start, seed=seed + number, jacobian=True, algorithm="lbfgs")
            except RuntimeError as err:
                logger.info("optimisation from start %d failed: %s", number + 1, err)
                out.append(({}, -np.inf, -np.inf))
                continue
            # no mass: CmdStan gives no gradients at chosen points here (BridgeStan would), so the peak's height
            # alone sorts the modes
            out.append(({name: np.asarray(v).reshape(1, 1, *np.shape(v)) for name, v in fit.stan_variables().items()},
                        float(fit.optimized_params_dict["lp__"]), float("nan")))
        return out

    def start_error(self, program: FlatProgram, data: dict[str, Any],
                    inits: list[dict[str, Any]] | None) -> str | None:
        """None: CmdStan's log_prob method needs every parameter's value, whose
        sizes only the data fix; a simulator failing at the start stops
        CmdStan's sampler at once instead, and calibrate rewrites its
        message as the start check would (fitting.simulator_check.explained)."""
        return None

    def log_density_functions(self, program: FlatProgram, data: dict[str, Any]):
        # cmdstanpy evaluates log densities one CmdStan process at a time and
        # has no unconstrain; BridgeStan would, but is not a dependency
        raise NotImplementedError("the modes' posterior masses need log densities at many "
                                  "unconstrained points, which the cmdstanpy backend does not "
                                  "provide; use backend='pystan' to weigh the modes")

    def unconstrained_quantities_function(self, program: FlatProgram, data: dict[str, Any]):
        # as log_density_functions: no unconstrained points without BridgeStan
        raise NotImplementedError("moment matching needs the log likelihood at many unconstrained "
                                  "points, which the cmdstanpy backend does not provide; use "
                                  "backend='pystan' to score high Pareto k points without refits")


def write_stan_csv(path: Path, parameters: Draws, chain: int, seed: int) -> Path:
    """One chain of parameter draws as a Stan CSV file that CmdStan's
    standalone generated quantities (and cmdstanpy.from_csv) accept: CmdStan's
    header comments, the sampler columns, then each parameter's elements
    (name.i.j, column-major)."""
    draws = next(iter(parameters.values())).shape[1]
    columns, values = [], []
    for name, array in parameters.items():
        shape = array.shape[2:]
        # column-major: the first index varies fastest
        for index in (tuple(reversed(i)) for i in product(*(range(n) for n in reversed(shape)))):
            columns.append(".".join([name, *(str(i + 1) for i in index)]))
            values.append(array[(chain, slice(None), *index)])
    sampler = np.zeros((draws, 7))
    table = np.column_stack([sampler, *values]) if values else sampler
    # fixed_param: the draws are given, so there is no adaptation block to write;
    # cmdstanpy wants warmup > 0 in the header even when none is saved
    header = "\n".join([
        "# stan_version_major = 2", "# stan_version_minor = 36", "# stan_version_patch = 0",
        "# model = stancal_model", "# method = sample (Default)", "#   sample",
        f"#     num_samples = {draws}", "#     num_warmup = 1", "#     save_warmup = false",
        "#     thin = 1", "#     adapt", "#       engaged = false", "#     algorithm = fixed_param",
        f"# id = {chain + 1}", "# random", f"#   seed = {seed}",
        ",".join(["lp__", "accept_stat__", "stepsize__", "treedepth__", "n_leapfrog__",
                  "divergent__", "energy__", *columns]),
    ])
    footer = ("# \n#  Elapsed Time: 0 seconds (Warm-up)\n#                0 seconds (Sampling)\n"
              "#                0 seconds (Total)\n# ")
    np.savetxt(path, table, delimiter=",", header=header, footer=footer, comments="", fmt="%.17g")
    return path
