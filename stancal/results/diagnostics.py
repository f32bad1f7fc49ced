"""Sampler checks after every fit, reported with numbers and advice."""

from __future__ import annotations

import warnings
from dataclasses import asdict, dataclass, field
from typing import TYPE_CHECKING

import numpy as np
import xarray as xr

from stancal.problem import advice

if TYPE_CHECKING:  # annotations only: results do not depend on the model's options
    from stancal.problem.options import ModelOptions



class SamplerWarning(UserWarning):
    """The sampler did not explore the posterior reliably."""


THETA_NAME_DIM = "theta_name"  # the dimensions whose coordinates are theta's names end so
RHAT_LIMIT = 1.01
ESS_PER_CHAIN = 100  # Vehtari et al. (2021): at least 100 bulk/tail ESS per chain


@dataclass
class Diagnostics:
    divergences: int
    draws: int
    max_rhat: float
    worst_rhat: str
    min_ess_bulk: float
    min_ess_tail: float
    worst_ess: str
    treedepth_hits: int
    low_bfmi_chains: list[int]
    messages: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not self.messages

    def to_dict(self) -> dict:
        return asdict(self)

    def summary(self) -> dict:
        """What summary.json and gap.json report of the sampler."""
        return {"divergences": self.divergences, "draws": self.draws, "max_rhat": self.max_rhat,
                "min_ess_bulk": self.min_ess_bulk, "min_ess_tail": self.min_ess_tail,
                "treedepth_hits": self.treedepth_hits, "low_bfmi_chains": self.low_bfmi_chains,
                "warnings": self.messages}


def _bfmi(energy: np.ndarray) -> np.ndarray:
    """Estimated Bayesian fraction of missing information per chain."""
    return np.square(np.diff(energy, axis=1)).mean(axis=1) / np.var(energy, axis=1)


def as_chains(posterior: xr.Dataset, chains: list[int]) -> xr.Dataset:
    """The given chains (a theta mode's); a single chain as its two halves,
    so that R-hat still compares the start of the chain with its end."""
    if len(chains) > 1:
        return posterior.isel(chain=chains)
    half = posterior.sizes["draw"] // 2
    one = posterior.isel(chain=chains[0]).drop_vars(["chain", "draw"], errors="ignore")
    return xr.concat([one.isel(draw=slice(0, half)), one.isel(draw=slice(half, 2 * half))], dim="chain")


def component_name(da: xr.DataArray, flat: int) -> str:
    """One component of a variable as the user names it: a theta by its own
    name (``omega``), a per-experiment theta with its experiment
    (``k[run 2]``), any other by its coordinates (``delta_length_scale[T]``)."""
    index = np.unravel_index(flat, da.shape) if da.ndim else ()
    labels = [(str(dim), str(da[dim].values[i]) if dim in da.coords else str(i))
              for dim, i in zip(da.dims, index, strict=True)]
    # a dimension of parameter names (results.result, results.vector_result) names the component itself
    own = [label for dim, label in labels if dim.endswith(THETA_NAME_DIM)]
    rest = [label for dim, label in labels if not dim.endswith(THETA_NAME_DIM)]
    return (own[0] if own else str(da.name)) + (f"[{', '.join(rest)}]" if rest else "")


def _extreme(ds: xr.Dataset, largest: bool) -> tuple[float, str]:
    """The largest (or smallest) value over every variable, and where it is."""
    best, where = (-np.inf if largest else np.inf), ""
    for name, da in ds.data_vars.items():
        values = np.nan_to_num(np.asarray(da, dtype=float).ravel(), nan=np.inf if largest else -np.inf)
        if values.size == 0:
            continue
        i = int(np.argmax(values) if largest else np.argmin(values))
        value = values[i]
        if (value > best) if largest else (value < best):
            best, where = float(value), component_name(da.rename(name), i)
    return best, where


def check_sampler(posterior: xr.Dataset, sample_stats: xr.Dataset, max_treedepth: int,
                  parameters: list[str], modes: list[list[int]] | None = None) -> Diagnostics:
    """Check divergences, R-hat, ESS, tree depth and E-BFMI of ``parameters``.
    ``modes``: the chains of each theta mode, when there are several; R-hat
    is then taken within each mode (chains in different modes disagree by
    design, and the modes are weighed separately)."""
    import arviz_stats as ast

    chains = posterior.sizes["chain"]
    groups = modes if modes and len(modes) > 1 else [list(range(chains))]
    rhat = xr.concat([ast.rhat(as_chains(posterior[parameters], group)) for group in groups],
                     dim="mode").max("mode")
    # the modes' draws are independent samples of their parts of the posterior: their ESS add up
    ess_bulk = sum(ast.ess(as_chains(posterior[parameters], group), method="bulk") for group in groups)
    ess_tail = sum(ast.ess(as_chains(posterior[parameters], group), method="tail") for group in groups)
    max_rhat, worst_rhat = _extreme(rhat, largest=True)
    min_bulk, worst_bulk = _extreme(ess_bulk, largest=False)
    min_tail, worst_tail = _extreme(ess_tail, largest=False)
    bfmi = _bfmi(np.asarray(sample_stats["energy"]))
    diagnostics = Diagnostics(
        divergences=int(np.asarray(sample_stats["diverging"]).sum()), draws=chains * posterior.sizes["draw"],
        max_rhat=max_rhat, worst_rhat=worst_rhat, min_ess_bulk=min_bulk, min_ess_tail=min_tail,
        worst_ess=worst_bulk if min_bulk <= min_tail else worst_tail,
        treedepth_hits=int((np.asarray(sample_stats["tree_depth"]) >= max_treedepth).sum()),
        low_bfmi_chains=[int(c) for c in np.flatnonzero(bfmi < 0.3)])
    diagnostics.messages = _messages(diagnostics, chains, max_treedepth, bfmi, several_modes=len(groups) > 1)
    return diagnostics


def _messages(d: Diagnostics, chains: int, max_treedepth: int, bfmi: np.ndarray, several_modes: bool) -> list[str]:
    """Each problem of the fit, with its numbers, where it is, and what to do
    (the options named as the reader writes them: stancal.problem.advice)."""
    messages = []
    longer = 2 * d.draws // chains  # twice the draws per chain
    if d.divergences:
        messages.append(
            f"{d.divergences} of {d.draws} transitions diverged ({100 * d.divergences / d.draws:.1f} %): "
            f"the posterior has regions the sampler cannot follow. Raise the target acceptance "
            f"({advice.option('adapt_delta', 0.95)} or 0.99), or rescale the problem; do not trust the draws "
            "near them."
        )
    if d.max_rhat > RHAT_LIMIT:
        messages.append(
            f"R-hat up to {d.max_rhat:.3f} ({d.worst_rhat}) > {RHAT_LIMIT}: chains "
            + ("within a theta mode " if several_modes else "") + "disagree. "
            f"Run longer ({advice.options(warmup=longer, draws=longer)})"
            + ("." if several_modes else f"; if chains sit in different theta modes, see {advice.place('modes')}.")
        )
    min_ess = min(d.min_ess_bulk, d.min_ess_tail)
    if min_ess < ESS_PER_CHAIN * chains:
        messages.append(
            f"effective sample size down to {min_ess:.0f} ({d.worst_ess}; bulk {d.min_ess_bulk:.0f}, "
            f"tail {d.min_ess_tail:.0f}) < {ESS_PER_CHAIN * chains} ({ESS_PER_CHAIN} per chain): "
            f"intervals are imprecise. Draw more samples ({advice.option('draws', longer)})."
        )
    if d.treedepth_hits:
        messages.append(
            f"{d.treedepth_hits} of {d.draws} transitions hit the maximum tree depth {max_treedepth}: "
            f"sampling was slow and may be incomplete. Raise it ({advice.option('max_treedepth', max_treedepth + 2)})"
            " or rescale the problem."
        )
    if d.low_bfmi_chains:
        messages.append(
            f"E-BFMI below 0.3 in chains {d.low_bfmi_chains} "
            f"({', '.join(f'{b:.2f}' for b in bfmi[d.low_bfmi_chains])}): "
            "the sampler explores the energy poorly; consider reparameterising."
        )
    return messages


def report(diagnostics: Diagnostics) -> None:
    """Each message as a warning, once: the caller shows it (Python's warnings,
    the command line's "warning:" lines, a fit runner naming the fit)."""
    for message in diagnostics.messages:
        warnings.warn(message, SamplerWarning, stacklevel=3)


def parametrization_advice(options: ModelOptions, diagnostics: Diagnostics) -> list[str]:
    """The other parametrization of theta(x)'s latent GP, when a fit with
    functional theta struggled. Measured on the beam case: centred mixes well when the data pin
    theta(x) (noise 0.1 mm, 3 loads per temperature: no tree-depth hits) and
    hits the maximum tree depth in 70 % of transitions when they do not
    (noise 1 mm, one load per temperature); non-centred is the reverse."""
    struggled = (diagnostics.treedepth_hits or diagnostics.low_bfmi_chains or diagnostics.divergences
                 or diagnostics.max_rhat > RHAT_LIMIT)
    if not options.functional or not struggled:
        return []
    other = "non_centred" if options.functional_parametrization == "centred" else "centred"
    when = ("suits noisy or sparse data, which leave theta(x) loosely pinned" if other == "non_centred"
            else "suits data that pin theta(x) closely")
    return [(f"theta(x)'s latent GP was sampled {options.functional_parametrization}; if the trouble "
            f"above involves theta_function_*, try "
             f"{advice.config_key('model', 'functional_parametrization', other)} ({when}).")]
