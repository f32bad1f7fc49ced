"""cmdstanpy: used when the user has a CmdStan installation."""

from __future__ import annotations

import logging
import os
import time
from pathlib import Path
from typing import Any

import numpy as np

from ..stan_source import FlatProgram, StanProgramError
from .base import SAMPLER_STATS, Draws, SampleOutput, StanRuntimeError

logger = logging.getLogger("stancal")

def cmdstan_available() -> bool:
    try:
        import cmdstanpy

        cmdstanpy.cmdstan_path()
        return True
    except Exception:  # cmdstanpy raises ValueError or OSError when absent
        return False


def cache_dir() -> Path:
    root = os.environ.get("STANCAL_CACHE") or os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(root) / "stancal" / "cmdstan"


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
    ) -> SampleOutput:
        started = time.perf_counter()
        model = self._model(program)
        compiled = time.perf_counter()
        try:
            fit = model.sample(
                data=data, chains=chains, parallel_chains=min(chains, os.cpu_count() or 1),
                iter_warmup=warmup, iter_sampling=draws, seed=seed, inits=inits,
                adapt_delta=adapt_delta, max_treedepth=max_treedepth, show_progress=True,
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
            compile_seconds=compiled - started,
            sample_seconds=finished - compiled,
        )

    def generate_quantities(
        self, program: FlatProgram, data: dict[str, Any], parameters: Draws, seed: int
    ) -> Draws:
        # CmdStan's standalone generated quantities needs the fit's CSV files,
        # which a result loaded from netCDF no longer has; PyStan's write_array
        # runs the same program on any draws.
        return self.quantities_function(program, data, seed)(parameters)

    def quantities_function(self, program: FlatProgram, data: dict[str, Any], seed: int):
        from .pystan_backend import PyStanBackend

        return PyStanBackend().quantities_function(program, data, seed)
