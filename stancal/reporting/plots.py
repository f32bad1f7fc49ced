"""Figures of a calibration: theta posteriors, zeta over the data, delta."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from stancal.problem.noise import HETEROSCEDASTIC, noise_input_names
from stancal.reporting.series import Curves, axis_label, fit_curves, series_rows
from stancal.results.result import CalibrationResult


def pyplot():
    """matplotlib.pyplot on the file-only Agg backend (no display needed)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


LEVEL = "90 %"  # every band and interval in these figures: 5 % to 95 % quantiles
THETA_COLUMNS = 4  # theta's panels per row: eleven in one row (Al-5083) were unreadable at a page's width


def _density(values: np.ndarray, low: float, high: float) -> tuple[np.ndarray, np.ndarray]:
    """A Gaussian kernel density estimate on a fine grid over [low, high]."""
    from scipy.stats import gaussian_kde

    grid = np.linspace(low, high, 300)
    if np.ptp(values) == 0:  # one value: no spread to estimate a density from
        return grid, np.where(np.isclose(grid, values[0]), 1.0, 0.0)
    return grid, gaussian_kde(values)(grid)


def _per(units: dict[str, str] | None, name: str) -> str:
    """The unit of a density over ``name``: " [min]" for 1/min, " [1/m]" for m."""
    unit = (units or {}).get(name)
    if not unit:
        return ""
    if unit.startswith("1/"):
        return f" [{unit[2:]}]"
    return f" [1/({unit})]" if any(c in unit for c in "/ ·*") else f" [1/{unit}]"


def _posterior_view(values: np.ndarray, p) -> tuple[float, float]:
    """The posterior's own range, with a margin, inside the prior's box."""
    low, high = np.quantile(values, [0.001, 0.999])
    pad = 0.15 * (high - low) or 0.01 * (p.upper - p.lower)
    return max(p.lower, low - pad), min(p.upper, high + pad)


def plot_theta(result: CalibrationResult, path: str | Path | None = None, units: dict[str, str] | None = None):
    """Posterior density of each theta over the posterior's own range, one
    colour per mode, its central 90 % interval shaded, and the uniform
    prior as a dashed reference; THETA_COLUMNS panels a row."""
    plt = pyplot()
    posterior = result.idata["posterior"]
    # a cheap simulator's own theta_l (Goh et al. 2013) in panels after theta's
    low = list(getattr(result.data, "low_parameters", [])) if "theta_low" in posterior else []
    params = [*result.data.parameters, *low]
    columns = min(len(params), THETA_COLUMNS)
    rows = -(-len(params) // columns)
    fig, axes = plt.subplots(rows, columns, figsize=(4.2 * columns, 3.4 * rows), squeeze=False,
                             layout="constrained")
    for ax in axes.flat[len(params):]:  # the last row's empty places
        ax.set_visible(False)
    theta = np.concatenate([np.asarray(posterior["theta"]), *([np.asarray(posterior["theta_low"])] if low else [])],
                           axis=-1)
    groups = [m.chains for m in result.modes] or [list(range(theta.shape[0]))]
    for k, (ax, p) in enumerate(zip(axes.flat, params, strict=False)):
        low, high = _posterior_view(theta[..., k].ravel(), p)
        for g, chains in enumerate(groups):
            values = theta[chains, :, k].ravel()
            grid, density = _density(values, low, high)
            label = f"mode {g + 1} (chains {chains})" if len(groups) > 1 else "posterior"
            ax.plot(grid, density, color=f"C{g}", label=label)
            q05, q95 = np.quantile(values, [0.05, 0.95])
            inside = (grid >= q05) & (grid <= q95)
            ax.fill_between(grid[inside], density[inside], color=f"C{g}", alpha=0.3,
                            label=f"{LEVEL} interval" if g == 0 else None)
        ax.axhline(1 / (p.upper - p.lower), color="grey", ls="--", lw=1, label="prior (uniform on θ's bounds)")
        ax.set_xlim(low, high)
        ax.set_ylim(bottom=0)
        ax.set_xlabel(axis_label(p.name, units))
        ax.set_ylabel("posterior density" + _per(units, p.name))
    # one legend below the panels, where it covers no density
    fig.legend(*axes.flat[0].get_legend_handles_labels(), loc="outside lower center", ncols=3, fontsize=7)
    fig.suptitle(f"θ posterior ({result.method})")
    return finish(fig, path)


def plot_fit(result: CalibrationResult, path: str | Path | None = None, units: dict[str, str] | None = None,
             curves: Curves | None = None):
    """The true process zeta as a 90 % band and median per series along the
    input that varies most, the calibrated simulator f dashed, and the data
    on top (each point in its series' colour)."""
    plt = pyplot()
    curves = fit_curves(result, units) if curves is None else curves
    data, column = result.data, curves.along
    fig, ax = plt.subplots(figsize=(7, 4.5), layout="constrained")
    if curves.on_grid:
        _bands(ax, curves, "zeta", "ζ (reality)", with_f=True)
        if len(curves.labels) == 1 and "y_q05" in curves.table:
            ax.fill_between(*_sorted(curves.table, column, "y_q05", "y_q95"), color="C0", alpha=0.1,
                            zorder=1, label=f"new observation, {LEVEL} band")
    else:  # too many series for curves: the prediction at each data point
        _intervals(ax, curves.table, column, "zeta", f"ζ (reality) at the data points, {LEVEL} interval")
    _data_points(ax, data, column, curves)
    _censored_ranges(ax, result, column)
    ax.set_xlabel(axis_label(column, units))
    ax.set_ylabel(axis_label(data.output, units))
    ax.legend(fontsize=7, loc="best")
    _title(ax, f"Calibrated prediction of reality along {column}", curves)
    return finish(fig, path)


def _title(ax, title: str, curves: Curves) -> None:
    others = [label.split(" = ")[0] for label in curves.labels[0].split(", ")] if curves.labels[0] else []
    held = f"\ncovariates held: {curves.held}" if curves.held else ""
    ax.set_title(title + (f", one band per {', '.join(others)}" if others else "")
                 + ("" if curves.on_grid else " (at the data points)") + held, fontsize=9)


def _sorted(table: pd.DataFrame, column: str, *names: str) -> list[np.ndarray]:
    order = np.argsort(table[column].to_numpy(), kind="stable")
    return [table[column].to_numpy()[order], *(table[n].to_numpy()[order] for n in names)]


def _bands(ax, curves: Curves, quantity: str, name: str, with_f: bool = False) -> None:
    """One ribbon (zorder 1) and median line (zorder 2) per series; the
    data go on top (zorder 3), so no band hides under them."""
    for s, label in enumerate(curves.labels):
        part = curves.table[curves.table["series"] == s]
        x, lo, mid, hi = _sorted(part, curves.along, f"{quantity}_q05", f"{quantity}_q50", f"{quantity}_q95")
        prefix = f"{label}: " if label else ""
        ax.fill_between(x, lo, hi, color=f"C{s}", alpha=0.3, lw=0, zorder=1,
                        label=f"{prefix}{name}, {LEVEL} band")
        ax.plot(x, mid, color=f"C{s}", lw=1.5, zorder=2)
        if with_f:
            x, f = _sorted(part, curves.along, "f_q50")
            ax.plot(x, f, color=f"C{s}", ls="--", lw=1, zorder=2)
    if with_f:  # one legend entry for every series' dashed line
        ax.plot([], [], color="0.3", ls="--", lw=1, label="simulator f(x, θ), median")


def _intervals(ax, table: pd.DataFrame, column: str, quantity: str, label: str) -> None:
    mid = table[f"{quantity}_q50"].to_numpy()
    ax.errorbar(table[column], mid, yerr=[mid - table[f"{quantity}_q05"], table[f"{quantity}_q95"] - mid],
                fmt="_", ms=8, capsize=2, color="C0", alpha=0.8, zorder=2, label=label)


def _data_points(ax, data, column: str, curves: Curves) -> None:
    """The measured points, small and on top, in their series' colour."""
    series = series_rows(data, column) if len(curves.labels) > 1 else None
    colour = np.zeros(len(data.physical), dtype=int)
    for s, (_, rows) in enumerate(series or []):
        colour[rows] = s
    observed = data.observations.observed
    ax.scatter(data.physical[column].to_numpy()[observed], data.physical[data.output].to_numpy()[observed],
               s=14, c=[f"C{s}" for s in colour[observed]], edgecolors="k", linewidths=0.6, zorder=3)
    ax.scatter([], [], s=14, color="0.7", edgecolors="k", linewidths=0.6, label="physical data")


def plot_discrepancy(result: CalibrationResult, path: str | Path | None = None,
                     units: dict[str, str] | None = None, curves: Curves | None = None):
    """delta with its 90 % band along the input that varies most, one band per series."""
    plt = pyplot()
    curves = fit_curves(result, units) if curves is None else curves
    fig, ax = plt.subplots(figsize=(7, 4.2), layout="constrained")
    if curves.on_grid:
        _bands(ax, curves, "delta", "δ")
    else:
        _intervals(ax, curves.table, curves.along, "delta", f"δ at the data points, {LEVEL} interval")
    ax.axhline(0, color="k", lw=0.8)
    ax.set_xlabel(axis_label(curves.along, units))
    unit = (units or {}).get(result.data.output)
    ax.set_ylabel(f"discrepancy δ in {result.data.output}" + (f" [{unit}]" if unit else ""))
    ax.legend(fontsize=7)
    _title(ax, "Model discrepancy δ = reality − simulator", curves)
    return finish(fig, path)


def plot_source_biases(result: CalibrationResult, path: str | Path | None = None,
                       units: dict[str, str] | None = None, curves: Curves | None = None):
    """Each biased source's bias b_s (its readings minus reality, beside the
    shared discrepancy δ; functions/source_bias.stan, Gu et al. 2023) with its
    90 % band along the input that varies most, one panel per biased source."""
    plt = pyplot()
    curves = fit_curves(result, units) if curves is None else curves
    names = result.options.biased_sources
    fig, axes = plt.subplots(1, len(names), figsize=(6 * len(names), 3.8), squeeze=False, layout="constrained")
    unit = (units or {}).get(result.data.output)
    for ax, name in zip(axes[0], names, strict=True):
        if curves.on_grid:
            _bands(ax, curves, f"bias_{name}", f"bias of {name}")
        else:
            _intervals(ax, curves.table, curves.along, f"bias_{name}", f"bias at the data points, {LEVEL} interval")
        ax.axhline(0, color="k", lw=0.8)
        ax.set_xlabel(axis_label(curves.along, units))
        ax.set_ylabel(f"bias of {name} in {result.data.output}" + (f" [{unit}]" if unit else ""))
        ax.legend(fontsize=7)
        _title(ax, f"Bias of source {name} = its reading − the true process", curves)
    return finish(fig, path)


def _censored_ranges(ax, result: CalibrationResult, column: str) -> None:
    """Censored observations as the range they are known to lie in, with an
    arrow where a side is open."""
    obs = result.data.observations
    if not obs.any_censored:
        return
    x = result.data.physical[column].to_numpy()
    low, high = ax.get_ylim()
    for n, i in enumerate(np.flatnonzero(~obs.observed)):
        lower = obs.lower[i] if np.isfinite(obs.lower[i]) else low
        upper = obs.upper[i] if np.isfinite(obs.upper[i]) else high
        ax.plot([x[i], x[i]], [lower, upper], color="0.4", lw=1.2, alpha=0.7,
                label="censored: known range" if n == 0 else None)
        marker = "v" if not np.isfinite(obs.lower[i]) else ("^" if not np.isfinite(obs.upper[i]) else "_")
        ax.scatter([x[i]], [obs.upper[i] if marker == "v" else obs.lower[i]], marker=marker,
                   color="0.4", s=22, zorder=3)
    ax.set_ylim(low, high)


def plot_theta_functions(result: CalibrationResult, path: str | Path | None = None,
                         units: dict[str, str] | None = None):
    """Each functional theta against each input it varies over: posterior
    mean and 90 % band (averaged over the other functional inputs)."""
    plt = pyplot()
    curves = result.theta_functions()
    inputs = list(result.options.functional_inputs)
    fig, axes = plt.subplots(len(curves), len(inputs), figsize=(5.5 * len(inputs), 3.6 * len(curves)),
                             squeeze=False, layout="constrained")
    for row, (name, curve) in enumerate(curves.items()):
        table = pd.DataFrame({**curve["inputs"], "mean": curve["mean"], "q05": curve["q05"],
                              "q95": curve["q95"]})
        for ax, column in zip(axes[row], inputs, strict=False):
            along = table.groupby(column)[["mean", "q05", "q95"]].mean()
            ax.fill_between(along.index, along["q05"], along["q95"], alpha=0.3, color="C4",
                            label=f"{name}({column}), {LEVEL} band")
            ax.plot(along.index, along["mean"], color="C4")
            p = next(p for p in result.data.parameters if p.name == name)
            ax.set_ylim(p.lower, p.upper)
            ax.set_xlabel(axis_label(column, units))
            ax.set_ylabel(axis_label(name, units))
            ax.legend(fontsize=8)
    fig.suptitle("functional calibration parameters")
    return finish(fig, path)


def plot_noise_sd(result: CalibrationResult, path: str | Path | None = None, units: dict[str, str] | None = None):
    """Heteroscedastic noise: the noise sd's posterior mean and 90 % band
    along the noise input with the most settings (one band over one input;
    intervals at the settings of several), with each replicated setting's
    sample sd of its readings, a model-free check (docs/noise.md)."""
    plt = pyplot()
    curve = result.noise_curve()
    inputs = noise_input_names(result.options, result.data)
    column = max(inputs, key=lambda c: curve[c].nunique())
    fig, ax = plt.subplots(figsize=(6, 3.6), layout="constrained")
    if len(inputs) == 1:
        ax.fill_between(curve[column], curve["q05"], curve["q95"], color="C1", alpha=0.3, lw=0,
                        label=f"noise sd, {LEVEL} band")
        ax.plot(curve[column], curve["mean"], color="C1", label="noise sd, posterior mean")
    else:
        ax.errorbar(curve[column], curve["mean"], yerr=[curve["mean"] - curve["q05"], curve["q95"] - curve["mean"]],
                    fmt="o", color="C1", ms=3, label=f"noise sd at each setting, mean and {LEVEL} interval")
    physical = result.data.physical
    spread = physical.groupby(list(result.data.discrepancy_inputs))[result.data.output].agg(["std", "count"])
    spread = spread[spread["count"] > 1].reset_index()
    if len(spread):
        ax.scatter(spread[column], spread["std"], color="0.3", s=12, zorder=3,
                   label="sample sd of each setting's replicates")
    ax.set_xlabel(axis_label(column, units))
    ax.set_ylabel(axis_label(result.data.output, units).replace(result.data.output, "noise sd", 1))
    ax.set_ylim(bottom=0)
    ax.legend(fontsize=8)
    ax.set_title("measurement noise sd (heteroscedastic)", fontsize=10)
    return finish(fig, path)


def finish(fig, path):
    """Save ``fig`` to ``path`` and close it; without a path, return it open."""
    if path is not None:
        fig.savefig(path, dpi=110)
        pyplot().close(fig)
    return fig


def write_plots(result: CalibrationResult, folder: str | Path, units: dict[str, str] | None = None) -> list[Path]:
    """theta.png, fit.png, and discrepancy.png, theta_functions.png,
    noise_sd.png (heteroscedastic noise) and source_bias.png (biased sources)
    where the model has them; ``units``: the config's [units] (name -> unit)."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    paths = [folder / "theta.png", folder / "fit.png"]
    curves = fit_curves(result, units)  # one prediction on the grid for fit.png and discrepancy.png
    plot_theta(result, paths[0], units)
    plot_fit(result, paths[1], units, curves)
    if result.options.discrepancy != "none":
        paths.append(folder / "discrepancy.png")
        plot_discrepancy(result, paths[-1], units, curves)
    if result.options.functional:
        paths.append(folder / "theta_functions.png")
        plot_theta_functions(result, paths[-1], units)
    if result.options.noise == HETEROSCEDASTIC:
        paths.append(folder / "noise_sd.png")
        plot_noise_sd(result, paths[-1], units)
    if result.options.biased_sources:
        paths.append(folder / "source_bias.png")
        plot_source_biases(result, paths[-1], units, curves)
    return paths


def plot_vector_curves(result, path: str | Path | None = None, units: dict[str, str] | None = None):
    """One panel per experiment: zeta's 90 % band and the calibrated
    simulator f along the output index, with the measured values."""
    plt = pyplot()
    data = result.data
    predictions = result.idata["predictions"]
    column = data.output_index[0]
    along = np.asarray(predictions[column])
    zeta = np.asarray(predictions["zeta"]).reshape(-1, *predictions["zeta"].shape[2:])
    f = np.asarray(predictions["f"]).reshape(-1, *predictions["f"].shape[2:])
    names = list(data.experiments.index)
    columns = min(3, len(names)) if len(names) <= 9 else 4
    rows = -(-len(names) // columns)
    fig, axes = plt.subplots(rows, columns, figsize=(3.6 * columns, 2.9 * rows + 0.4), squeeze=False, sharey=True,
                             layout="constrained")
    for e, (ax, name) in enumerate(zip(axes.ravel(), names, strict=False)):
        low, high = np.quantile(zeta[:, e], [0.05, 0.95], axis=0)
        ax.fill_between(along, low, high, color="C0", alpha=0.3, lw=0, zorder=1, label=f"ζ (reality), {LEVEL} band")
        ax.plot(along, np.median(zeta[:, e], axis=0), color="C0", lw=1.2, zorder=2)
        ax.plot(along, np.median(f[:, e], axis=0), color="C1", ls="--", lw=1.2, zorder=2,
                label="simulator f, median")
        measured = data.physical[data.physical[data.experiment] == name]
        ax.scatter(measured[column], measured[data.output], s=10, color="k", zorder=3, label="measured")
        ax.set_title(name, fontsize=9)
        ax.set_xlabel(axis_label(column, units))
    for ax in axes.ravel()[len(names):]:
        ax.set_visible(False)
    for row in axes:
        row[0].set_ylabel(axis_label(data.output, units))
    axes[0][0].legend(fontsize=7)
    fig.suptitle(f"Calibrated prediction per experiment ({result.method})")
    return finish(fig, path)
