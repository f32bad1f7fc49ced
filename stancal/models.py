"""The single registry of stancal's Stan programs and their integer codes."""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum, StrEnum
from pathlib import Path

from .stan_source import shipped_models_dir


class Kernel(IntEnum):
    """``kernel_id`` in the Stan programs (see functions/gp_kernels.stan)."""

    SE = 1
    MATERN52 = 2


class Method(StrEnum):
    KOH = "koh"
    KOH_EMULATOR = "koh_emulator"
    MODULAR = "modular"


@dataclass(frozen=True)
class ModelSpec:
    """One Stan program stancal ships."""

    name: str
    stan_file: str
    needs_simulator: bool  # includes the user's simulator.stan
    needs_runs: bool  # needs a table of simulator runs
    description: str

    @property
    def path(self) -> Path:
        return shipped_models_dir() / self.stan_file


MODELS: dict[str, ModelSpec] = {
    spec.name: spec
    for spec in (
        ModelSpec("koh", "koh.stan", True, False,
                  "KOH with a cheap simulator written in Stan"),
        ModelSpec("koh_emulator", "koh_emulator.stan", False, True,
                  "full KOH: emulator and calibration in one joint GP"),
        ModelSpec("emulator", "emulator.stan", False, True,
                  "GP emulator of simulator runs (stage 1 of modular)"),
        ModelSpec("modular", "modular.stan", False, True,
                  "modular KOH: stage 2 with the stage-1 emulator fixed"),
    )
}


def model_spec(name: str) -> ModelSpec:
    try:
        return MODELS[name]
    except KeyError:
        raise ValueError(
            f"unknown model {name!r}; choose one of {', '.join(MODELS)}"
        ) from None
