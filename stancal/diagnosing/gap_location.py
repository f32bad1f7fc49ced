"""Where the simulator is wrong, read from the posterior of the discrepancy:
how much delta depends on each input and covariate (Sobol indices computed
per posterior draw) and the ranges where its main effect is credibly
non-zero.

For each posterior draw, delta at the physical points is interpolated with
that draw's kernel, m(u) = k(u, X) K^-1 delta(X); a Hilbert-space
discrepancy (the scalable programs) is evaluated from its basis instead. Sobol indices use the
mean of delta given the draw's parameters (so that the noise of a single
draw of delta is not mistaken for structure); main effects and their bands
use the draws of delta themselves. Both are estimated on a quasi-random
design with numeric variables uniform over their observed range and
categorical ones at their observed frequencies, independently
(Saltelli et al. 2010, Jansen 1999 estimators).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd
from scipy.linalg import cho_factor, cho_solve
from scipy.stats import qmc

from stancal.numerics.hsgp import HSGPBasis
from stancal.numerics.hsgp import basis as hsgp_basis
from stancal.numerics.kernels import ard_cross_cov
from stancal.results.result import CalibrationResult
from stancal.results.summaries import band

_JITTER = 1e-6  # relative to a unit-variance kernel; keeps interpolation stable


def interval(values: np.ndarray) -> dict[str, float]:
    """Mean and 90 % interval of draws, ignoring NaN."""
    values = np.asarray(values, dtype=float)
    values = values[np.isfinite(values)]
    if values.size == 0:
        return {"mean": float("nan"), "q05": float("nan"), "q50": float("nan"), "q95": float("nan")}
    return {k: float(v) for k, v in band(values).items()}


@dataclass
class MainEffect:
    """E[delta | variable = value], averaged over the other variables, per draw."""

    variable: str
    values: list  # grid in original units, or the levels of a categorical variable
    draws: np.ndarray  # (draws, len(values)), output units
    categorical: bool

    def band(self) -> pd.DataFrame:
        return pd.DataFrame({"value": self.values, **band(self.draws)})

    def regions(self) -> list[dict]:
        """Ranges (or levels) where the 90 % band excludes zero. A region
        over the whole range says the gap is there whatever the variable's
        value: it does not locate the gap along this variable."""
        band = self.band()
        sign = np.where(band.q05 > 0, 1, np.where(band.q95 < 0, -1, 0))
        whole = bool((sign == sign[0]).all())
        if self.categorical:
            return [{"variable": self.variable, "from": v, "to": v, "sign": _sign_word(s),
                     "whole_range": whole} for v, s in zip(self.values, sign, strict=True) if s != 0]
        out, start = [], 0
        for k in range(1, len(sign) + 1):
            if k == len(sign) or sign[k] != sign[start]:
                if sign[start] != 0:
                    out.append({"variable": self.variable, "from": float(self.values[start]),
                                "to": float(self.values[k - 1]), "sign": _sign_word(sign[start]),
                                "whole_range": whole})
                start = k
        return out


def _sign_word(sign: int) -> str:
    return "simulator too low" if sign > 0 else "simulator too high"


@dataclass
class ConditionalEffect:
    """The discrepancy along an output index with one other variable held
    low or high (at 1/6 or 5/6 of its range), averaged over the rest: where
    along a curve the gap sits, for which experiments."""

    given: str
    level: str  # "low" or "high"
    value: float  # the given variable's value, original units
    effect: MainEffect  # along the index

    def to_json(self) -> dict:
        return {"index": self.effect.variable, "given": self.given, "level": self.level, "value": self.value,
                "regions": self.effect.regions()}


@dataclass
class GapLocation:
    importance: dict[str, dict[str, float]]  # total Sobol index per variable
    first_order: dict[str, dict[str, float]]  # first-order Sobol index per variable
    main_effects: dict[str, MainEffect]
    at_observations: pd.DataFrame  # delta (GP part) at each physical point
    along_index: list[ConditionalEffect] = field(default_factory=list)  # vector outputs

    @property
    def regions(self) -> list[dict]:
        return [r for effect in self.main_effects.values() for r in effect.regions()]

    def to_json(self) -> dict:
        return {"importance": self.importance, "first_order": self.first_order,
                "regions": self.regions,
                "along_index": [c.to_json() for c in self.along_index],
                "observations_with_credible_gap": int(self.at_observations["credible"].sum())}


class _Design:
    """Points on the unit scale of the discrepancy columns: two independent
    base samples and, per variable, a grid of its values."""

    CONDITION_LEVELS = {"low": 1 / 6, "high": 5 / 6}  # where along its range a variable is held

    def __init__(self, result: CalibrationResult, base_points: int, grid_size: int, seed: int,
                 along: tuple[str, ...] = ()):
        data = result.data
        self.columns = data.discrepancy_inputs
        self.variables = data.discrepancy_variables
        self.categorical = set(data.levels)
        x_obs = data.scaling.to_unit(data.physical, self.columns)
        index = {c: i for i, c in enumerate(self.columns)}
        self.slots = {v: [index[c] for c in cols] for v, cols in self.variables.items()}
        rng = np.random.default_rng(seed)
        numeric = [v for v in self.variables if v not in self.categorical]
        sobol = qmc.Sobol(2 * len(numeric), scramble=True, seed=rng).random(base_points)
        self.A = np.zeros((base_points, len(self.columns)))
        self.B = np.zeros_like(self.A)
        self.grid: dict[str, tuple[np.ndarray, np.ndarray, list]] = {}  # unit rows, weights, labels
        for k, v in enumerate(numeric):
            i = self.slots[v][0]
            lo, hi = x_obs[:, i].min(), x_obs[:, i].max()
            self.A[:, i] = lo + (hi - lo) * sobol[:, 2 * k]
            self.B[:, i] = lo + (hi - lo) * sobol[:, 2 * k + 1]
            unit = np.linspace(lo, hi, grid_size)
            labels = list(data.scaling.low[v] + data.scaling.width[v] * unit)
            self.grid[v] = (unit[:, None], np.full(grid_size, 1 / grid_size), labels)
        for v in self.categorical & set(self.variables):
            cols = self.slots[v]
            freq = x_obs[:, cols].mean(0)
            for target in (self.A, self.B):
                level = rng.choice(len(cols), size=base_points, p=freq)
                target[:, cols] = np.eye(len(cols))[level]
            self.grid[v] = (np.eye(len(cols)), freq, list(data.levels[v]))
        # index variable a along its grid, another numeric variable held low or high
        self.conditions = []
        for a in along:
            for v in (v for v in numeric if v not in along):
                column = x_obs[:, self.slots[v][0]]
                self.conditions += [(a, v, level, column.min() + share * np.ptp(column))
                                    for level, share in self.CONDITION_LEVELS.items()]

    def with_variable(self, base: np.ndarray, variable: str, values: np.ndarray) -> np.ndarray:
        out = base.copy()
        out[:, self.slots[variable]] = values
        return out

    def points(self) -> tuple[np.ndarray, dict[str, slice]]:
        """Every point the estimators need, stacked, with the block of each."""
        blocks, where, start = [], {}, 0

        def add(name: str, rows: np.ndarray) -> None:
            nonlocal start
            blocks.append(rows)
            where[name] = slice(start, start + len(rows))
            start += len(rows)

        add("A", self.A)
        add("B", self.B)
        for v in self.variables:
            add(f"AB:{v}", self.with_variable(self.A, v, self.B[:, self.slots[v]]))
            unit_rows = self.grid[v][0]
            for g, row in enumerate(unit_rows):
                add(f"grid:{v}:{g}", self.with_variable(self.A, v, np.broadcast_to(row, (len(self.A), len(row)))))
        for a, v, level, unit in self.conditions:
            # a quarter of the base points average out the other variables well enough for a curve
            base = self.A[:max(len(self.A) // 4, 16)]
            held = self.with_variable(base, v, np.full((len(base), 1), unit))
            for g, row in enumerate(self.grid[a][0]):
                add(f"cond:{a}:{v}:{level}:{g}", self.with_variable(held, a, np.broadcast_to(row, (len(held), 1))))
        return np.vstack(blocks), where


def discrepancy_parts(result: CalibrationResult, name: str = "delta_gp") -> tuple[np.ndarray, np.ndarray]:
    """Draws of the GP part of delta at the physical points (draws, N) and of
    the constant term of its mean (draws,), zero without one; output units.
    ``name``: delta_gp (draws of delta) or delta_gp_mean (its mean given the
    parameters; the latent programs sample delta, so they have draws only)."""
    at_observations = result.idata["at_observations"]
    delta = np.asarray(at_observations[name if name in at_observations else "delta_gp"])
    delta = delta.reshape(-1, delta.shape[-1])
    posterior = result.idata["posterior"]
    if "beta" in posterior and "Intercept" in posterior["beta"].coords["mean_term"].values:
        return delta, np.asarray(posterior["beta"].sel(mean_term="Intercept")).ravel()
    return delta, np.zeros(len(delta))


def _hsgp_discrepancy(result: CalibrationResult, points: np.ndarray):
    """Draw s -> the Hilbert-space discrepancy's GP part at ``points`` (unit
    cube), output units: the program's basis and that draw's weights."""
    basis = HSGPBasis(result.options.basis_functions, result.options.boundary_factor)
    phi = result.data.scaling.y_scale * hsgp_basis(points, basis.index, basis.boundary)
    weights = np.asarray(result.idata["discrepancy_basis"]["weights"]).reshape(-1, basis.size)
    return lambda s: phi @ weights[s]


def locate_gap(result: CalibrationResult, *, max_draws: int = 200, base_points: int = 128,
               grid_size: int = 25, seed: int = 0, along: tuple[str, ...] = ()) -> GapLocation:
    """Importance and main effects of the discrepancy of a fitted result
    (its GP part plus any constant mean term). ``along``: a vector output's
    index column(s), along which the discrepancy is also drawn with each
    other numeric variable held low and high."""
    if not result.options.has_discrepancy:
        raise ValueError("locating the gap needs a GP discrepancy (discrepancy = 'gp')")
    data = result.data
    delta, constant = discrepancy_parts(result)
    delta_mean, _ = discrepancy_parts(result, "delta_gp_mean")
    # each draw's length scales on the unit scale of the discrepancy inputs
    widths = np.array([data.scaling.width[c] for c in data.discrepancy_inputs])
    length_scale = np.asarray(result.idata["posterior"]["delta_length_scale"]).reshape(-1, len(widths)) / widths
    rng = np.random.default_rng(seed)
    chosen = np.sort(rng.choice(len(delta), size=min(max_draws, len(delta)), replace=False))
    design = _Design(result, base_points, grid_size, seed, tuple(along))
    points, where = design.points()
    x_obs = data.scaling.to_unit(data.physical, design.columns)
    kernel_id = result.options.kernel_id

    total = {v: [] for v in design.variables}
    first = {v: [] for v in design.variables}
    effects = {v: [] for v in design.variables}
    conditional = {c[:3]: [] for c in design.conditions}
    at_points = _hsgp_discrepancy(result, points) if result.options.basis_functions else None
    for s in chosen:
        if at_points is not None:  # the Hilbert-space discrepancy is defined everywhere: no n x n solve
            m_draw = m_mean = at_points(s)
        else:
            K = ard_cross_cov(x_obs, x_obs, kernel_id, 1.0, length_scale[s])
            alpha = cho_solve(cho_factor(K + _JITTER * np.eye(len(K))),
                              np.column_stack([delta[s], delta_mean[s]]))
            m_draw, m_mean = (ard_cross_cov(points, x_obs, kernel_id, 1.0, length_scale[s]) @ alpha).T
        mA, mB = m_mean[where["A"]], m_mean[where["B"]]
        variance = np.var(np.concatenate([mA, mB]))
        ok = variance > 1e-12 * (np.mean(delta_mean[s] ** 2) + 1e-300)
        for v in design.variables:
            mAB = m_mean[where[f"AB:{v}"]]
            total[v].append(0.5 * np.mean((mA - mAB) ** 2) / variance if ok else np.nan)
            first[v].append(np.mean(mB * (mAB - mA)) / variance if ok else np.nan)
            effects[v].append([m_draw[where[f"grid:{v}:{g}"]].mean() + constant[s]
                               for g in range(len(design.grid[v][0]))])
        for a, v, level in conditional:
            conditional[a, v, level].append([m_draw[where[f"cond:{a}:{v}:{level}:{g}"]].mean() + constant[s]
                                             for g in range(len(design.grid[a][0]))])

    main = {v: MainEffect(v, design.grid[v][2], np.array(effects[v]), v in design.categorical)
            for v in design.variables}
    delta = delta + constant[:, None]
    observed = data.source[list(design.variables)].reset_index(drop=True).copy()
    for k, v in band(delta).items():
        observed[f"delta_{k}"] = v
    observed["credible"] = (observed.delta_q05 > 0) | (observed.delta_q95 < 0)
    return GapLocation(
        # a Sobol index lies in [0, 1]; the Monte Carlo estimates (Jansen's total,
        # Saltelli's first order) can stray past either end, and clipping only
        # moves them closer to the truth
        importance={v: interval(np.clip(total[v], 0, 1)) for v in design.variables},
        first_order={v: interval(np.clip(first[v], 0, 1)) for v in design.variables},
        main_effects=main, at_observations=observed,
        along_index=[ConditionalEffect(v, level, float(data.scaling.low[v] + data.scaling.width[v] * unit),
                                       MainEffect(a, design.grid[a][2], np.array(conditional[a, v, level]), False))
                     for a, v, level, unit in design.conditions])
