"""The one interface between stancal and a Stan interface library."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from ..stan_source import FlatProgram

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


class StanRuntimeError(RuntimeError):
    """Stan rejected the data or failed while sampling."""


@dataclass
class SampleOutput:
    draws: Draws
    sample_stats: Draws  # lp, diverging, tree_depth, n_steps, step_size, energy, ...
    max_treedepth: int
    compile_seconds: float
    sample_seconds: float
    messages: list[str] = field(default_factory=list)


class StanBackend(Protocol):
    name: str

    def check(self, program: FlatProgram) -> None:
        """Raise StanProgramError, with the user's file and line, if stanc rejects the program."""
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
    ) -> SampleOutput: ...

    def generate_quantities(
        self,
        program: FlatProgram,
        data: dict[str, Any],
        parameters: Draws,
        seed: int,
    ) -> Draws:
        """Rerun generated quantities for given parameter draws (chain, draw, ...)."""
        ...

    def quantities_function(
        self, program: FlatProgram, data: dict[str, Any], seed: int
    ) -> Callable[[Draws], Draws]:
        """generate_quantities with the program and data bound once, for many calls."""
        ...
