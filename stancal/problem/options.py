"""What a user may choose about the model (not the sampler): the options of
the scalar and vector programs, and the limits they are checked against."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from stancal.problem.codes import NOISE_MODES, Kernel
from stancal.problem.noise import check_noise_inputs, check_noise_name

APPROXIMATIONS = ("auto", "exact", "hsgp")
KERNELS = ("se", "matern52")


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
    # the mean terms centred over the physical points without a constant term: a theta carries
    # the level (stancal.fitting.confounding dropped the constant it would trade with)
    mean_centred: bool = False
    # the latent programs' discrepancy GP: centred, non_centred, partial (partially non-centred with the
    # data's information, where the program offers it), or auto (the plan chooses from the data's
    # information per point: stancal.numerics.parametrization); the reason says who chose and why
    discrepancy_parametrization: str = "auto"
    discrepancy_parametrization_reason: str = field(default="", metadata={"set_by": "stancal"})  # not a user's key
    # the measurement noise: iid, per_source, student_t or heteroscedastic (stancal.problem.noise,
    # functions/noise.stan)
    noise: str = "iid"
    # heteroscedastic noise: the simulator inputs its log sd varies over (empty: all of them)
    noise_inputs: tuple[str, ...] = ()
    # the sources (of the data's source column) whose readings carry a bias GP of their own beside
    # the discrepancy; the others are references (stancal.problem.source_bias, functions/source_bias.stan)
    biased_sources: tuple[str, ...] = ()
    # a stochastic simulator: its replicated runs' scatter is its own variance, which the emulator of
    # its mean carries (stochastic kriging, Ankenman, Nelson & Staum 2010; docs/noise.md); a property
    # of the simulator, so its config key is in [simulator], not [model]
    stochastic: bool = field(default=False, metadata={"set_by": "[simulator] stochastic"})

    def __post_init__(self) -> None:
        # lists from a config or a saved result; one name given as a string is that name, not its letters
        for name in ("functional", "functional_inputs", "basis_functions", "boundary_factor", "noise_inputs",
                     "biased_sources"):
            value = getattr(self, name)
            object.__setattr__(self, name, (value,) if isinstance(value, str) else tuple(value))
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
        if self.discrepancy_parametrization not in PARAMETRIZATIONS:
            raise ValueError(f"discrepancy_parametrization must be one of {', '.join(PARAMETRIZATIONS)}; "
                             f"got {self.discrepancy_parametrization!r}")
        if self.kernel not in KERNELS:
            raise ValueError(f"kernel must be 'se' or 'matern52'; got {self.kernel!r}")
        check_noise_name(self.noise)
        check_noise_inputs(self.noise, self.noise_inputs)
        if self.scaled_lambda is not None and not (np.isfinite(self.scaled_lambda) and self.scaled_lambda > 0):
            raise ValueError(f"scaled_lambda must be a positive number; got {self.scaled_lambda!r}")

    @property
    def kernel_id(self) -> int:
        return int(Kernel.SE if self.kernel == "se" else Kernel.MATERN52)

    @property
    def has_discrepancy(self) -> bool:
        return self.discrepancy != "none"


FUNCTIONAL_PARAMETRIZATIONS = ("centred", "non_centred")
# the latent discrepancy: auto = chosen by the plan (stancal.numerics.parametrization)
PARAMETRIZATIONS = ("auto", "centred", "non_centred", "partial")

# approximation = "auto" switches to the scalable programs when the dense
# matrix factorised at every gradient would be larger than this: N physical
# points for koh, N points + M runs for the emulators (benchmarks/scaling.py:
# past it a dense fit of 4 x (500 + 500) draws takes more than about ten minutes)
EXACT_SIZE_LIMIT = 1000

# discrepancy_form in koh.stan; "none" switches the discrepancy off
DISCREPANCIES = {"gp": 1, "orthogonal": 2, "scaled": 3, "none": 1}
RESTRICTED_DISCREPANCIES = ("orthogonal", "scaled")  # restricted_gp.stan, koh.stan only


@dataclass(frozen=True)
class VectorOptions:
    """The model of one vector-output fit (what stancal.diagnosing.gap_location reads)."""

    discrepancy: str = "gp"  # gp | none
    noise: str = "one"  # see problem.codes.NOISE_MODES
    kernel: str = "se"
    mean_formula: str | None = None
    mean_intercept: bool = False
    basis_functions: int = 0  # the vector programs' discrepancy is an exact GP

    def __post_init__(self) -> None:
        if self.noise not in NOISE_MODES:
            raise ValueError(f"noise must be one of {sorted(NOISE_MODES)}; got '{self.noise}'")
        if self.discrepancy not in ("gp", "none"):
            raise ValueError(f"discrepancy must be 'gp' or 'none' for a vector output; got '{self.discrepancy}'")
        if self.kernel not in KERNELS:
            raise ValueError(f"kernel must be 'se' or 'matern52'; got '{self.kernel}'")

    @property
    def has_discrepancy(self) -> bool:
        return self.discrepancy == "gp"

    @property
    def kernel_id(self) -> int:
        return int(Kernel.SE if self.kernel == "se" else Kernel.MATERN52)
