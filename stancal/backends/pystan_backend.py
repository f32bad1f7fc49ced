"""PyStan 3 (httpstan): the embedded backend that needs only pip and g++."""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from ..stan_source import FlatProgram, StanProgramError
from .base import SAMPLER_STATS, Draws, SampleOutput, StanRuntimeError

logger = logging.getLogger("stancal")

def _is_compiled(code: str) -> bool:
    import httpstan.cache
    import httpstan.models

    try:
        name = httpstan.models.calculate_model_name(code)
        return httpstan.cache.model_directory(name).exists()
    except Exception:  # cache layout is httpstan's business; assume a compile
        return False


def _by_chain(flat: np.ndarray, dims: list[int], chains: int) -> np.ndarray:
    """PyStan's (*dims, draw * chains) with chain varying fastest -> (chain, draw, *dims)."""
    draws = flat.shape[-1] // chains
    return np.moveaxis(flat.reshape(*dims, draws, chains), [-1, -2], [0, 1])


class PyStanBackend:
    name = "pystan"

    def _build(self, program: FlatProgram, data: dict[str, Any], seed: int):
        import stan

        if not _is_compiled(program.code):
            self.check(program)
            logger.warning(
                "Compiling Stan program %s with PyStan; the first compile takes about a "
                "minute, later runs use the cache.", program.origin[0][0] if program.origin else "?"
            )
        try:
            return stan.build(program.code, data=data, random_seed=seed)
        except ValueError as err:  # stanc errors and data errors arrive as ValueError
            raise StanProgramError(program.explain(str(err))) from None
        except RuntimeError as err:
            raise StanRuntimeError(program.explain(str(err))) from None

    @staticmethod
    def check(program: FlatProgram) -> None:
        """Run stanc alone (no C++, a fraction of a second). PyStan's build
        error keeps only 'Semantic error'; stanc gives the whole message."""
        import httpstan.compile

        try:
            httpstan.compile.compile(program.code, "stancal_check")
        except ValueError as err:
            raise StanProgramError(program.explain(str(err))) from None

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
        model = self._build(program, data, seed)
        compiled = time.perf_counter()
        kwargs: dict[str, Any] = dict(
            num_chains=chains, num_warmup=warmup, num_samples=draws,
            delta=adapt_delta, max_depth=max_treedepth,
        )
        if inits is not None:
            kwargs["init"] = inits
        try:
            fit = model.sample(**kwargs)
        except RuntimeError as err:
            raise StanRuntimeError(self._explain_failure(model, program, inits, err)) from None
        finished = time.perf_counter()
        names = [n for n in fit.param_names]
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
            compile_seconds=compiled - started,
            sample_seconds=finished - compiled,
        )

    @staticmethod
    def _explain_failure(model, program: FlatProgram, inits, err: RuntimeError) -> str:
        """httpstan 4.17 can lose Stan's message while reporting a failed run;
        evaluating the log density at the first init usually recovers it."""
        message = str(err)
        if inits:
            # variables the init leaves to Stan get 0.5, inside every constraint stancal's
            # programs use (transformed parameters and generated quantities are ignored)
            point = {name: np.full(dims, 0.5).tolist() for name, dims in zip(model.param_names, model.dims)}
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
        HTTP round trips per draw. httpstan seeds every call's RNG with 0, so
        _rng draws repeat from one parameter draw to the next."""
        import httpstan.models

        model = self._build(program, data, seed)
        services = httpstan.models.import_services_extension_module(model.model_name)
        names = list(model.param_names)
        dims = [list(d) for d in model.dims]

        def run(parameters: Draws) -> Draws:
            chains, draws = next(iter(parameters.values())).shape[:2]
            flat_rows = []
            try:
                for c in range(chains):
                    for d in range(draws):
                        point = {k: np.asarray(v[c, d]).tolist() for k, v in parameters.items()}
                        unconstrained = services.transform_inits(model.data, point)
                        flat_rows.append(services.write_array(model.data, unconstrained, True, True))
            except RuntimeError as err:
                raise StanRuntimeError(program.explain(f"Stan failed in generated quantities: {err}")) from None
            flat = np.asarray(flat_rows, dtype=float)  # (chain * draw, all constrained names)
            out: Draws = {}
            offset = 0
            for name, shape in zip(names, dims):
                size = int(np.prod(shape))
                if name not in parameters:
                    block = flat[:, offset : offset + size].reshape(chains, draws, *reversed(shape))
                    # Stan flattens column-major: put the variable's axes back in order
                    out[name] = block.transpose(0, 1, *range(block.ndim - 1, 1, -1))
                offset += size
            return out

        return run
