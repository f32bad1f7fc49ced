"""Chains that settle in different theta modes: detect and describe them
instead of reporting a blended mean."""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field, replace

import numpy as np
import pandas as pd

from stancal.numerics.mode_mass import bridge_log_mass, mode_weights
from stancal.problem import advice
from stancal.problem.data import InputRangeWarning


class MultimodalWarning(UserWarning):
    """Chains found separate modes of the theta posterior."""


@dataclass
class Mode:
    chains: list[int]
    theta_mean: dict[str, float]
    theta_q05: dict[str, float]
    theta_q95: dict[str, float]
    mean_log_density: float
    # share of the posterior mass (mode_mass.py) with its 90 % Monte Carlo
    # interval; None when it could not be estimated
    weight: float | None = None
    weight_q05: float | None = None
    weight_q95: float | None = None
    log_mass: float | None = None
    log_mass_se: float | None = None
    # where its theta mean lies beyond the simulator runs' range, one phrase per theta (beyond_runs)
    beyond_runs: list[str] = field(default_factory=list)

    def to_dict(self) -> dict:
        return {
            "chains": self.chains,
            "theta": {k: {"mean": self.theta_mean[k], "q05": self.theta_q05[k],
                          "q95": self.theta_q95[k]} for k in self.theta_mean},
            "mean_log_density": self.mean_log_density,
            "weight": None if self.weight is None else {
                "mean": self.weight, "q05": self.weight_q05, "q95": self.weight_q95},
            "log_mass": self.log_mass, "log_mass_se": self.log_mass_se, "beyond_runs": self.beyond_runs,
        }


def _separated(a: np.ndarray, b: np.ndarray, unit_width: np.ndarray) -> bool:
    """Two chains (draw, theta) sit in different modes when, for some theta,
    their central 90 % intervals do not overlap and their means differ by
    more than 3 % of the theta box (tiny gaps are sampling noise)."""
    lo_a, hi_a = np.quantile(a, [0.05, 0.95], axis=0)
    lo_b, hi_b = np.quantile(b, [0.05, 0.95], axis=0)
    apart = (hi_a < lo_b) | (hi_b < lo_a)
    far = np.abs(a.mean(0) - b.mean(0)) > 0.03 * unit_width
    return bool(np.any(apart & far))


def find_modes(theta: np.ndarray, lp: np.ndarray, names: list[str],
               widths: np.ndarray) -> list[Mode]:
    """Group chains into modes. ``theta``: (chain, draw, n_theta) in original
    units; ``lp``: (chain, draw) log density; ``widths``: theta box widths."""
    chains = theta.shape[0]
    parent = list(range(chains))

    def root(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for i in range(chains):
        for j in range(i + 1, chains):
            if not _separated(theta[i], theta[j], widths):
                parent[root(j)] = root(i)
    groups: dict[int, list[int]] = {}
    for c in range(chains):
        groups.setdefault(root(c), []).append(c)
    modes = []
    for members in groups.values():
        pooled = theta[members].reshape(-1, theta.shape[-1])
        modes.append(Mode(
            chains=members,
            theta_mean=dict(zip(names, pooled.mean(0).tolist(), strict=True)),
            theta_q05=dict(zip(names, np.quantile(pooled, 0.05, axis=0).tolist(), strict=True)),
            theta_q95=dict(zip(names, np.quantile(pooled, 0.95, axis=0).tolist(), strict=True)),
            mean_log_density=float(lp[members].mean()),
        ))
    return sorted(modes, key=lambda m: -m.mean_log_density)


def weigh(modes: list[Mode], unconstrained: np.ndarray, log_density, lp: np.ndarray,
          rng: np.random.Generator) -> list[Mode]:
    """Each mode's share of the posterior mass by bridge sampling
    (mode_mass.py), heaviest first. ``unconstrained``: (chain, draw, d)
    draws on the unconstrained scale; ``lp``: (chain, draw) log density, for
    the draws' effective sample size."""
    import arviz_stats as ast

    masses = []
    for mode in modes:
        draws = unconstrained[mode.chains].reshape(-1, unconstrained.shape[-1])
        effective = float(ast.ess(lp[mode.chains], method="bulk"))
        masses.append(bridge_log_mass(draws, log_density, rng, effective))
    weights, low, high = mode_weights(masses, rng)
    weighed = [replace(mode, weight=float(w), weight_q05=float(lo), weight_q95=float(hi),
                       log_mass=m.log_mass, log_mass_se=m.log_mass_se)
               for mode, w, lo, hi, m in zip(modes, weights, low, high, masses, strict=True)]
    return sorted(weighed, key=lambda m: -m.weight)


def modes_of(tree, names: list[str], widths: np.ndarray, log_density_functions,
             seed: int) -> tuple[list[Mode], str | None]:
    """The chains' theta modes of a fit's DataTree, weighed by posterior mass
    when there are several; ``log_density_functions()`` gives the program's
    (unconstrain, log_density), or raises NotImplementedError (the reason is
    returned); None when the draws are not a density's (L2's projections)."""
    lp = np.asarray(tree["sample_stats"]["lp"])
    modes = find_modes(np.asarray(tree["posterior"]["theta"]), lp, names, widths)
    if len(modes) <= 1 or log_density_functions is None:
        return modes, None
    try:
        unconstrain, log_density = log_density_functions()
    except NotImplementedError as err:
        return modes, str(err)
    parameters = {k: np.asarray(v) for k, v in tree["stan_parameters"].data_vars.items()}
    return weigh(modes, unconstrain(parameters), log_density, lp, np.random.default_rng(seed)), None


def beyond_runs(modes: list[Mode], runs_theta: pd.DataFrame | None) -> list[Mode]:
    """Each mode with the theta whose mean lies beyond the range of the runs
    the emulator was trained on (``runs_theta``: their theta columns, the
    calibrated simulator's runs alone where there are several fidelities;
    None: no emulator). There the emulator extrapolates, its mean returns
    to its trend and its variance to its prior's, so the mode may be the
    emulator's rather than the simulator's (docs/multifidelity.md: a mode of
    weight 0.002 at k = 1.964, beyond the highest expensive run at 1.756)."""
    if runs_theta is None:
        return modes
    marked = []
    for mode in modes:
        notes = []
        for name, value in mode.theta_mean.items():
            if name in runs_theta:
                low, high = float(runs_theta[name].min()), float(runs_theta[name].max())
                if value > high:
                    notes.append(f"{name} {value:.4g} above the highest run's {high:.4g}")
                elif value < low:
                    notes.append(f"{name} {value:.4g} below the lowest run's {low:.4g}")
        marked.append(replace(mode, beyond_runs=notes))
    return marked


def describe(modes: list[Mode]) -> str:
    parts = []
    for k, m in enumerate(modes, start=1):
        theta = ", ".join(f"{n} {m.theta_mean[n]:.4g} [{m.theta_q05[n]:.4g}, {m.theta_q95[n]:.4g}]"
                          for n in m.theta_mean)
        mass = (f"weight {m.weight:.3f} [{m.weight_q05:.3f}, {m.weight_q95:.3f}]" if m.weight is not None
                else f"mean log density {m.mean_log_density:.1f}")
        beyond = (f" (beyond the simulator runs: {', '.join(m.beyond_runs)}; the emulator extrapolates there)"
                  if m.beyond_runs else "")
        parts.append(f"mode {k} (chains {m.chains}, {mass}): {theta}{beyond}")
    return "; ".join(parts)


def report(modes: list[Mode], weights_unavailable: str | None = None) -> None:
    if len(modes) > 1:
        if modes[0].weight is not None:
            how = ("theta is summarised as their mixture, each mode weighted by its posterior mass "
                   "(bridge sampling; 90 % Monte Carlo intervals)")
        else:
            how = (f"their posterior masses could not be estimated ({weights_unavailable}), so the "
                   "summary is that of the mode with the highest log density, which is not "
                   "necessarily the heaviest")
        message = (
            f"the chains found {len(modes)} separate theta modes: {describe(modes)}. {how}. "
            f"Summaries per mode are in {advice.place('summary by mode')}; more chains, or narrower theta bounds, "
            "show whether there are modes no chain found."
        )
        warnings.warn(message, MultimodalWarning, stacklevel=3)
    if modes and modes[0].beyond_runs:  # the posterior itself, or its heaviest mode
        where = "theta's posterior" if len(modes) == 1 else "theta's heaviest mode"
        warnings.warn(InputRangeWarning(
            f"{where} lies beyond the simulator runs: {', '.join(modes[0].beyond_runs)}; the emulator extrapolates "
            "there (its mean returns to its trend, its variance to its prior's), so the posterior rests on the "
            "emulator's prior more than on the simulator: add runs that reach it"), stacklevel=3)
