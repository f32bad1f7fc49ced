"""The single registry of stancal's Stan programs and their integer codes."""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum, StrEnum
from pathlib import Path

import numpy as np

from stancal.stan.source import shipped_models_dir


class Kernel(IntEnum):
    """``kernel_id`` in the Stan programs (see functions/gp_kernels.stan)."""

    SE = 1
    MATERN52 = 2


class Likelihood(IntEnum):
    """``likelihood_id`` in the latent programs (functions/observation_model.stan)."""

    GAUSSIAN = 1
    POISSON = 2
    NEGBINOMIAL = 3
    BINOMIAL = 4


class Censoring(IntEnum):
    """``censoring`` codes per observation (functions/observation_model.stan)."""

    OBSERVED = 0
    LEFT = 1  # y <= upper
    RIGHT = 2  # y >= lower
    INTERVAL = 3  # lower <= y <= upper


class Method(StrEnum):
    KOH = "koh"
    KOH_EMULATOR = "koh_emulator"
    MODULAR = "modular"
    KOH_LATENT = "koh_latent"
    KOH_LATENT_EMULATOR = "koh_latent_emulator"
    KOH_HSGP = "koh_hsgp"
    MODULAR_HSGP = "modular_hsgp"


# the latent-GP program that takes over a method's job when the outputs are
# non-Gaussian or censored, or theta is functional
LATENT_PROGRAM = {Method.KOH: Method.KOH_LATENT, Method.KOH_EMULATOR: Method.KOH_LATENT_EMULATOR,
                  Method.MODULAR: Method.KOH_LATENT_EMULATOR,
                  Method.KOH_LATENT: Method.KOH_LATENT,
                  Method.KOH_LATENT_EMULATOR: Method.KOH_LATENT_EMULATOR}

# the scalable program that takes over a method's job for many points or runs
# (review section 8.4): a Hilbert-space discrepancy, and an emulator of
# precomputed weights in place of the joint or modular GP emulator
SCALABLE_PROGRAM = {Method.KOH: Method.KOH_HSGP, Method.KOH_EMULATOR: Method.MODULAR_HSGP,
                    Method.MODULAR: Method.MODULAR_HSGP, Method.KOH_HSGP: Method.KOH_HSGP,
                    Method.MODULAR_HSGP: Method.MODULAR_HSGP}
HSGP_METHODS = (Method.KOH_HSGP, Method.MODULAR_HSGP)
APPROXIMATIONS = ("auto", "exact", "hsgp")


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
        ModelSpec("koh_latent", "koh_latent.stan", True, False,
                  "KOH with latent GPs: counts, binomial, censored outputs, functional theta"),
        ModelSpec("koh_latent_emulator", "koh_latent_emulator.stan", False, True,
                  "koh_latent from simulator runs: stage-1 emulator on the link scale, latent at the data"),
        ModelSpec("koh_hsgp", "koh_hsgp.stan", True, False,
                  "koh for thousands of points: Hilbert-space GP discrepancy"),
        ModelSpec("modular_hsgp", "modular_hsgp.stan", False, True,
                  "modular for thousands of runs and points: precomputed-weight emulator, "
                  "Hilbert-space GP discrepancy"),
        ModelSpec("koh_vector", "koh_vector.stan", True, False,
                  "KOH for a vector output with a cheap Stan simulator, ragged experiments"),
        ModelSpec("modular_vector", "modular_vector.stan", False, True,
                  "modular KOH for a vector output: one emulator GP per basis component, ragged experiments"),
    )
}


def model_spec(name: str) -> ModelSpec:
    try:
        return MODELS[name]
    except KeyError:
        raise ValueError(
            f"unknown model {name!r}; choose one of {', '.join(MODELS)}"
        ) from None


@dataclass(frozen=True)
class ModelOptions:
    """Choices that change the model, not the sampler."""

    discrepancy: str = "gp"  # see DISCREPANCIES
    kernel: str = "se"  # se | matern52
    estimate_rho: bool = False
    mean_formula: str | None = None  # discrepancy mean terms h(x, z)' beta, e.g. "I(v**2)"
    mean_intercept: bool = False  # a constant term in the discrepancy mean
    scaled_lambda: float | None = None  # scaled GP penalty lambda_z; None = sqrt(N)
    functional: tuple[str, ...] = ()  # theta that vary over functional_inputs (review section 8.2)
    functional_inputs: tuple[str, ...] = ()
    # theta(x)'s latent GP: "centred" (data that pin theta(x)) or "non_centred" (data that do not)
    functional_parametrization: str = "centred"
    # exact dense GPs, the scalable hsgp programs, or auto (by size: models.EXACT_SIZE_LIMIT)
    approximation: str = "auto"
    # the Hilbert-space discrepancy's basis per discrepancy input (stancal.numerics.hsgp);
    # empty: chosen by stancal from the length scales, and checked after the fit
    basis_functions: tuple[int, ...] = ()
    boundary_factor: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        # lists from a config or a saved result
        for name in ("functional", "functional_inputs", "basis_functions", "boundary_factor"):
            object.__setattr__(self, name, tuple(getattr(self, name)))
        if self.approximation not in APPROXIMATIONS:
            raise ValueError(f"approximation must be one of {', '.join(APPROXIMATIONS)}; "
                             f"got {self.approximation!r}")
        if (len(self.basis_functions) != len(self.boundary_factor)
                or any(m < 1 for m in self.basis_functions) or any(c < 1 for c in self.boundary_factor)):
            raise ValueError(f"basis_functions (counts >= 1) and boundary_factor (>= 1) need one value "
                             f"each per discrepancy input; got {list(self.basis_functions)} and "
                             f"{list(self.boundary_factor)}")
        if self.discrepancy not in DISCREPANCIES:
            raise ValueError(f"discrepancy must be one of {', '.join(DISCREPANCIES)}; "
                             f"got {self.discrepancy!r}")
        if self.functional_parametrization not in FUNCTIONAL_PARAMETRIZATIONS:
            raise ValueError(f"functional_parametrization must be one of "
                             f"{', '.join(FUNCTIONAL_PARAMETRIZATIONS)}; got {self.functional_parametrization!r}")
        if self.kernel not in ("se", "matern52"):
            raise ValueError(f"kernel must be 'se' or 'matern52'; got {self.kernel!r}")
        if self.scaled_lambda is not None and not (np.isfinite(self.scaled_lambda) and self.scaled_lambda > 0):
            raise ValueError(f"scaled_lambda must be a positive number; got {self.scaled_lambda!r}")

    @property
    def kernel_id(self) -> int:
        return int(Kernel.SE if self.kernel == "se" else Kernel.MATERN52)

    @property
    def has_discrepancy(self) -> bool:
        return self.discrepancy != "none"


FUNCTIONAL_PARAMETRIZATIONS = ("centred", "non_centred")

# approximation = "auto" switches to the scalable programs when the dense
# matrix factorised at every gradient would be larger than this: N physical
# points for koh, N points + M runs for the emulators (benchmarks/scaling.py:
# past it a dense fit of 4 x (500 + 500) draws takes more than about ten minutes)
EXACT_SIZE_LIMIT = 1000

# discrepancy_form in koh.stan; "none" switches the discrepancy off
DISCREPANCIES = {"gp": 1, "orthogonal": 2, "scaled": 3, "none": 1}
RESTRICTED_DISCREPANCIES = ("orthogonal", "scaled")  # restricted_gp.stan, koh.stan only
