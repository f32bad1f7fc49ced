"""Initial values: theta spread over its box, or in the posterior's modes
found by optimisation before sampling, so chains can find separate modes."""

from __future__ import annotations

import logging
import warnings
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from stancal.results.modes import MultimodalWarning

logger = logging.getLogger("stancal")


def spread_theta_inits(chains: int, n_theta: int, rng: np.random.Generator,
                       margin: float = 0.03) -> list[dict[str, list[float]]]:
    """A Latin hypercube over [margin, 1 - margin]^n_theta for theta_unit:
    each chain starts in its own stratum of every parameter. Other parameters
    get Stan's random inits."""
    strata = np.column_stack([rng.permutation(chains) for _ in range(n_theta)])
    unit = (strata + rng.uniform(size=(chains, n_theta))) / chains
    unit = margin + (1 - 2 * margin) * unit
    return [{"theta_unit": row.tolist()} for row in unit]


def theta_unit_init(values: dict[str, float], bounds: dict[str, tuple[float, float]],
                    rng: np.random.Generator, margin: float = 0.25) -> dict[str, list[float]]:
    """theta_unit at the natural ``values`` given (clipped into the box), in
    the order of ``bounds``; a parameter without a value starts at random in
    the middle of its range, [margin, 1 - margin]."""
    unit = [float(np.clip((values[name] - lo) / (hi - lo), 1e-3, 1 - 1e-3)) if name in values
            else float(rng.uniform(margin, 1 - margin)) for name, (lo, hi) in bounds.items()]
    return {"theta_unit": unit}


# a sampled emulator's nugget starts no nearer 0 than this (standardised units): stage 1's mode can sit at
# 1e-6, thirteen log units from the bulk of its half-normal(0, 0.05) prior, which warmup then has to cross
NUGGET_START_FLOOR = 1e-3


def fidelity_emulator_inits(hyperparameters: dict[str, Any] | None) -> dict[str, Any]:
    """Where koh_emulator's sampled multi-fidelity emulator starts: at stage
    1's estimates, level by level (Le Gratiet & Garnier 2014), the top
    level's as emulator_*, the cheaper ones' as low_emulator_*, each level's
    scale on the one below as level_rho. Empty without stage 1's levels
    (one fidelity: Stan's own inits, as before)."""
    levels = (hyperparameters or {}).get("levels")
    if not levels:
        return {}

    def start(level: dict[str, Any]) -> dict[str, Any]:
        return {"emulator_mean": float(level["emulator_mean"]), "emulator_sd": float(level["emulator_sd"]),
                "emulator_length_scale": [float(v) for v in level["emulator_length_scale"]],
                "emulator_nugget": max(float(level["emulator_nugget"]), NUGGET_START_FLOOR)}

    top, low = start(levels[-1]), [start(level) for level in levels[:-1]]
    return {**top, "level_rho": [float(level["rho"]) for level in levels[1:]],
            **{f"low_{name}": [level[name] for level in low] for name in top}}


# L-BFGS runs before sampling: at least this many, one per stratum of theta's box (spread_theta_inits), so that
# two chains do not depend on two starts (on Neddermeyer both spread chains stopped in corner modes)
START_OPTIMA = 8
# A mode this far (log units) below the best, by its peak's height (lp__) and by its Laplace mass alike, gets no
# chain: it holds less than e^-10 = 4.5e-5 of the best mode's mass. By height alone a low mode much wider than the
# best (each of two theta ten times wider) could hold comparable mass; the Laplace mass sees its width. Such modes
# are reported, not sampled.
MINOR_OPTIMUM_GAP = 10.0
# Optima whose theta (shared and per experiment, on the unit box) agree to this are one mode: L-BFGS stops within
# its tolerance of a mode, and stancal.results.modes counts chains 3 % of the box apart as separate
SAME_MODE = 0.02


@dataclass(frozen=True)
class Optimum:
    """Where one L-BFGS run ended: every variable there (draws (1, 1, ...)),
    lp__, the log Laplace mass (NaN: unknown) and the start it came from."""

    draws: dict[str, np.ndarray]
    log_density: float
    log_mass: float
    start: int

    def theta(self) -> np.ndarray:
        """Shared and per-experiment theta on the unit box, as one vector."""
        return np.concatenate([_unit(self.draws, "theta_unit").ravel(), _unit(self.draws, "theta_exp_unit").ravel()])


@dataclass(frozen=True)
class StartMode:
    """A theta optimum of the fit's log density, found before sampling."""

    theta_unit: tuple[float, ...]  # shared theta on the unit box
    theta_exp_unit: tuple[tuple[float, ...], ...]  # per-experiment theta on the unit box
    log_density: float  # lp__ at the optimum
    below_best: float  # the best optimum's lp__ minus this one's
    log_mass: float  # its Laplace mass (NaN where the backend cannot tell)
    mass_below_best: float  # the largest Laplace mass minus this one's (NaN: unknown)
    starts: int  # how many L-BFGS runs ended here
    chains: tuple[int, ...]  # the chains started here (none: far below the best)

    def to_dict(self, parameters) -> dict[str, Any]:
        """In the summary: shared theta in its units (``parameters``: the
        shared theta's, with name, lower, upper), per-experiment theta on its
        unit box."""
        theta = {p.name: p.lower + (p.upper - p.lower) * v for p, v in zip(parameters, self.theta_unit, strict=True)}
        return {"theta": theta, "theta_experiment_unit": [list(row) for row in self.theta_exp_unit],
                "log_density": self.log_density, "below_best": self.below_best,
                "log_mass": _number(self.log_mass), "mass_below_best": _number(self.mass_below_best),
                "starts": self.starts, "chains": list(self.chains)}

    def minor(self) -> bool:
        """Far below the best by height, and by mass where that is known."""
        return self.below_best > MINOR_OPTIMUM_GAP and not self.mass_below_best <= MINOR_OPTIMUM_GAP


def _number(value: float) -> float | None:
    return float(value) if np.isfinite(value) else None  # JSON has no NaN


def _unit(draws: dict[str, np.ndarray], name: str) -> np.ndarray:
    """A theta variable at an optimum (draws (1, 1, ...)); a backend may leave out a variable of size 0."""
    return np.asarray(draws[name][0, 0], dtype=float) if name in draws else np.zeros(0)


def group_optima(optima: list[Optimum]) -> list[list[Optimum]]:
    """The finite optima grouped by theta (within SAME_MODE on the unit box,
    shared and per experiment), best first; each group's members best first."""
    groups: list[list[Optimum]] = []
    for optimum in sorted((o for o in optima if np.isfinite(o.log_density)), key=lambda o: -o.log_density):
        at = optimum.theta()
        for group in groups:
            if np.all(np.abs(at - group[0].theta()) <= SAME_MODE):
                group.append(optimum)
                break
        else:
            groups.append([optimum])
    return groups


def _start_modes(groups: list[list[Optimum]], chains: int) -> list[StartMode]:
    """StartMode per group (its best optimum's height and mass); chains dealt
    round-robin over the modes not minor (within MINOR_OPTIMUM_GAP of the
    best by height or by mass), so comparable modes each get chains."""
    best = groups[0][0].log_density
    masses = np.array([g[0].log_mass for g in groups])
    top_mass = np.nanmax(masses) if np.isfinite(masses).any() else np.nan
    modes = [StartMode(tuple(_unit(g[0].draws, "theta_unit").tolist()),
                       tuple(map(tuple, _unit(g[0].draws, "theta_exp_unit").tolist())), g[0].log_density,
                       best - g[0].log_density, g[0].log_mass, top_mass - g[0].log_mass, len(g), ())
             for g in groups]
    kept = [k for k, m in enumerate(modes) if not m.minor()]
    if len(kept) > chains:
        warnings.warn(MultimodalWarning(
            f"{len(kept)} theta modes within {MINOR_OPTIMUM_GAP:g} log units of the best (by density or Laplace "
            f"mass); {chains} chains start in the best {chains} only: run at least {len(kept)} chains so that each "
            f"gets one"), stacklevel=3)
    dealt = {k: tuple(c for c in range(chains) if c % len(kept) == i) for i, k in enumerate(kept)}
    return [replace(m, chains=dealt.get(k, ())) for k, m in enumerate(modes)]


def mode_inits(stan_backend, program, stan_json: dict[str, Any], chains: int, n_theta: int,
               seed: int) -> tuple[list[dict[str, Any]], list[StartMode]]:
    """Chains start in the theta posterior's modes, found before sampling
    (Gelman et al. 2013, Bayesian Data Analysis, 3rd ed., §11.4 and §13.3:
    find the modes first, start the chains near them). L-BFGS on the fit's
    own log density from max(START_OPTIMA, chains) starts, theta spread over
    its box in strata (spread_theta_inits), the other parameters at Stan's
    random inits; the optima grouped into theta modes (group_optima), each
    with its Laplace mass (stancal.numerics.laplace) where the backend gives
    it. Chains go to the modes within MINOR_OPTIMUM_GAP of the best by
    height or by mass, in turn, so that separate modes that may hold
    comparable mass each get chains and stancal.results.modes weighs them by
    their bridge-sampled mass; a chain started in a minor mode far below
    would stay there and carry a weight its mass does not have (Yao, Vehtari
    & Gelman 2022, "Stacking for non-mixing Bayesian computations", JMLR
    23(79)). The modes far below get no chain and are logged and returned.
    Each chain starts its shared theta at the spread start of one of its
    mode's runs (per-experiment theta at that run's optimum); Stan draws the
    rest. Where no start reaches a finite density: theta spread over its box."""
    rng = np.random.default_rng(seed)
    starts = spread_theta_inits(max(START_OPTIMA, chains), n_theta, rng)
    ends = stan_backend.optima(program, stan_json, starts=starts, seed=seed)
    groups = group_optima([Optimum(draws, lp, mass, i) for i, (draws, lp, mass) in enumerate(ends)])
    if not groups:
        logger.info("no start of %d reached a finite log density: chains start spread over theta's box", len(starts))
        return spread_theta_inits(chains, n_theta, np.random.default_rng(seed)), []
    modes = _start_modes(groups, chains)
    inits = []
    for chain in range(chains):
        k = next(k for k, m in enumerate(modes) if chain in m.chains)
        # each of a mode's chains at the spread start of one of its runs, where the mode has several: in the mode's
        # basin, and apart, so that R-hat still compares chains from overdispersed starts (BDA3 section 11.4)
        optimum = groups[k][modes[k].chains.index(chain) % len(groups[k])]
        # per-experiment theta, which the starts leave to Stan, at the optimum: inside the mode too
        init = {"theta_unit": list(starts[optimum.start]["theta_unit"])}
        if "theta_exp_unit" in optimum.draws:  # rounded off a bound of the box, where Stan's init would fail
            init["theta_exp_unit"] = np.clip(_unit(optimum.draws, "theta_exp_unit"), 1e-9, 1 - 1e-9).tolist()
        inits.append(init)
    _log(modes, len(starts))
    return inits, modes


def _log(modes: list[StartMode], starts: int) -> None:
    def at(m: StartMode) -> str:
        return "(" + ", ".join(f"{v:.3f}" for v in m.theta_unit) + ")"

    def mass(m: StartMode) -> str:
        return f", Laplace mass {m.mass_below_best:.1f} below the largest" if np.isfinite(m.mass_below_best) else ""

    sampled = [m for m in modes if m.chains]
    logger.info("L-BFGS from %d starts found %d theta mode(s); chains start in %s", starts, len(modes),
                "; ".join(f"{at(m)} on the unit box, {m.below_best:.1f} below the best{mass(m)}: chains "
                          f"{list(m.chains)}" for m in sampled))
    for m in modes:
        if not m.chains and m.minor():  # not minor, more modes than chains: warned of
            logger.info("theta mode at %s on the unit box (%d of %d starts) gets no chain: its log density is "
                        "%.1f below the best (relative density %.1e < e^-%g)%s", at(m), m.starts, starts,
                        m.below_best, np.exp(-m.below_best), MINOR_OPTIMUM_GAP, mass(m))
