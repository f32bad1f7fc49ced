"""The one way stancal summarises draws: the mean and the 5/50/95 % quantiles;
for a posterior, with R-hat and ESS, per theta mode or as their mixture."""

from __future__ import annotations

from itertools import product

import numpy as np
import pandas as pd
import xarray as xr

from stancal.results.diagnostics import as_chains
from stancal.results.modes import Mode

QUANTILES = (0.05, 0.5, 0.95)


def band(draws: np.ndarray) -> dict[str, np.ndarray]:
    """Mean and quantiles over the first axis (the draws): keys mean, q05, q50, q95."""
    draws = np.asarray(draws, dtype=float)
    out = {"mean": draws.mean(0)}
    for q, value in zip(QUANTILES, np.quantile(draws, QUANTILES, axis=0), strict=True):
        out[f"q{round(q * 100):02d}"] = value
    return out


def weighted_quantiles(values: np.ndarray, weights: np.ndarray, quantiles) -> list[float]:
    """Quantiles of weighted draws (weights summing to 1), by interpolating
    the weighted empirical CDF at the draws' midpoints."""
    order = np.argsort(values)
    cumulative = np.cumsum(weights[order]) - 0.5 * weights[order]
    return [float(np.interp(q, cumulative, values[order])) for q in quantiles]


def posterior_table(posterior: xr.Dataset) -> pd.DataFrame:
    """One row per scalar of every variable: mean, sd, quantiles, R-hat, bulk ESS."""
    import arviz_stats as ast

    diag = ast.summary(posterior, kind="diagnostics", round_to="none")
    rows = []
    for name, da in posterior.data_vars.items():
        flat = np.asarray(da).reshape(da.sizes["chain"] * da.sizes["draw"], -1)
        extra_dims = [dim for dim in da.dims if dim not in ("chain", "draw")]
        # ArviZ's labels: name[a] or name[a, b], in C order like the reshape
        labels = [", ".join(str(v) for v in combo)
                  for combo in product(*(da[dim].values for dim in extra_dims))] if extra_dims else [None]
        for k, label in enumerate(labels):
            key = name if label is None else f"{name}[{label}]"
            v = flat[:, k]
            rows.append({
                "parameter": key, "mean": v.mean(), "sd": v.std(ddof=1),
                "q05": np.quantile(v, 0.05), "q50": np.quantile(v, 0.5),
                "q95": np.quantile(v, 0.95),
                "rhat": float(diag.loc[key, "r_hat"]),
                "ess_bulk": float(diag.loc[key, "ess_bulk"]),
            })
    return pd.DataFrame(rows).set_index("parameter")


def summary_by_mode(posterior: xr.Dataset, modes: list[Mode]) -> pd.DataFrame:
    """posterior_table, with several theta modes one block per mode
    (columns ``mode`` and ``weight``); a mode one chain holds is read as
    its two halves, so its R-hat is the health check's (check_sampler)."""
    if len(modes) <= 1:
        return posterior_table(posterior)
    blocks = []
    for k, mode in enumerate(modes, start=1):
        block = posterior_table(as_chains(posterior, mode.chains))  # R-hat as the health check takes it
        block.insert(0, "weight", np.nan if mode.weight is None else mode.weight)
        block.insert(0, "mode", k)
        blocks.append(block)
    return pd.concat(blocks)


def theta_summary(posterior: xr.Dataset, modes: list[Mode], theta_names: list[str],
                  variable: str = "theta") -> dict[str, dict[str, float]]:
    """theta's summary: with several modes whose masses are known, that of
    their mixture, each weighted by its mass (R-hat the worst within a mode,
    ESS the smallest); masses unknown, that of the first mode; never the
    chains blended. ``variable``: another parameter vector summarised the
    same way (theta_low, a cheap simulator's own theta_l)."""
    keys = ("mean", "sd", "q05", "q50", "q95", "rhat", "ess_bulk")
    if len(modes) > 1 and modes[0].weight is not None:
        theta = np.asarray(posterior[variable])  # (chain, draw, theta)
        draws = np.concatenate([theta[m.chains].reshape(-1, theta.shape[-1]) for m in modes])
        weights = np.concatenate([np.full(len(m.chains) * theta.shape[1], m.weight / (len(m.chains) * theta.shape[1]))
                                  for m in modes])
        per_mode = [posterior_table(as_chains(posterior[[variable]], m.chains)) for m in modes]
        out = {}
        for j, name in enumerate(theta_names):
            mean = float(weights @ draws[:, j])
            sd = float(np.sqrt(weights @ (draws[:, j] - mean) ** 2))
            label = f"{variable}[{name}]"
            out[name] = dict(zip(keys, [mean, sd, *weighted_quantiles(draws[:, j], weights, QUANTILES),
                                        max(float(t.loc[label, "rhat"]) for t in per_mode),
                                        min(float(t.loc[label, "ess_bulk"]) for t in per_mode)], strict=True))
        return out
    if len(modes) > 1:  # masses unknown (see modes.report)
        posterior = as_chains(posterior, modes[0].chains)  # one chain: its two halves, as the health check
    table = posterior_table(posterior[[variable]])
    return {name: {k: float(table.loc[f"{variable}[{name}]", k]) for k in keys} for name in theta_names}


def theta_function_summary(curves: np.ndarray, grid: pd.DataFrame,
                           names: list[str]) -> dict[str, dict]:
    """curves: (samples, grid point, functional theta) -> summary.json's
    theta_functions: per theta, the grid and the mean and 90 % band."""
    out = {}
    for k, name in enumerate(names):
        summary = band(curves[:, :, k])
        out[name] = {"inputs": {c: grid[c].tolist() for c in grid.columns},
                     **{q: summary[q].tolist() for q in ("mean", "q05", "q95")}}
    return out
