"""Figures of a calibration: theta posteriors, zeta over the data, delta."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from stancal.results.result import CalibrationResult


def pyplot():
    """matplotlib.pyplot on the file-only Agg backend (no display needed)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_theta(result: CalibrationResult, path: str | Path | None = None):
    """Posterior histogram of each theta over its prior box, one colour per mode."""
    plt = pyplot()
    params = result.data.parameters
    fig, axes = plt.subplots(1, len(params), figsize=(4 * len(params), 3.2), squeeze=False)
    theta = np.asarray(result.idata["posterior"]["theta"])
    groups = [m.chains for m in result.modes] or [list(range(theta.shape[0]))]
    for k, (ax, p) in enumerate(zip(axes[0], params, strict=False)):
        for g, chains in enumerate(groups):
            label = f"mode {g + 1} (chains {chains})" if len(groups) > 1 else "posterior"
            ax.hist(theta[chains, :, k].ravel(), bins=40, range=(p.lower, p.upper),
                    density=True, alpha=0.6, label=label)
        ax.axhline(1 / (p.upper - p.lower), color="grey", ls="--", lw=1, label="prior")
        ax.set_xlabel(p.name)
        ax.set_xlim(p.lower, p.upper)
    axes[0][0].legend(fontsize=8)
    fig.suptitle(f"theta posterior ({result.method})")
    fig.tight_layout()
    return finish(fig, path)


def _along(result: CalibrationResult):
    """The x axis for curve plots: the single input if there is one, else the first."""
    return result.data.discrepancy_inputs[0]


def plot_fit(result: CalibrationResult, path: str | Path | None = None):
    """zeta (90 % band) and the calibrated simulator against the data."""
    plt = pyplot()
    table = result.predict()
    column = _along(result)
    order = np.argsort(table[column].to_numpy())
    x = table[column].to_numpy()[order]
    fig, ax = plt.subplots(figsize=(6.5, 4))
    if len(result.data.discrepancy_inputs) == 1:
        ax.fill_between(x, table["y_q05"].to_numpy()[order], table["y_q95"].to_numpy()[order],
                        color="C0", alpha=0.15, label="new observation, 90 %")
        ax.fill_between(x, table["zeta_q05"].to_numpy()[order], table["zeta_q95"].to_numpy()[order],
                        color="C0", alpha=0.35, label="true process zeta, 90 %")
        ax.plot(x, table["zeta_q50"].to_numpy()[order], color="C0")
        ax.plot(x, table["f_q50"].to_numpy()[order], color="C3", ls="--", label="simulator f(x, theta)")
    else:  # points differ in other inputs too: no lines between them
        mid = table["zeta_q50"].to_numpy()
        ax.errorbar(table[column], mid, yerr=[mid - table["zeta_q05"], table["zeta_q95"] - mid],
                    fmt="o", ms=4, color="C0", label="true process zeta, 90 %")
        ax.scatter(table[column], table["f_q50"], marker="x", color="C3", label="simulator f(x, theta)")
    ax.scatter(result.data.physical[column], result.data.physical[result.data.output],
               s=14, color="k", zorder=3, label="physical data")
    _censored_ranges(ax, result, column)
    ax.set_xlabel(column)
    ax.set_ylabel(result.data.output)
    ax.legend(fontsize=8)
    ax.set_title("prediction of reality" if len(result.data.discrepancy_inputs) == 1
                 else f"prediction at the data points, against {column}")
    fig.tight_layout()
    return finish(fig, path)


def plot_discrepancy(result: CalibrationResult, path: str | Path | None = None):
    """delta with its 90 % band against each input and covariate."""
    plt = pyplot()
    table = result.predict()
    columns = list(result.data.discrepancy_variables)
    fig, axes = plt.subplots(1, len(columns), figsize=(5 * len(columns), 3.5), squeeze=False)
    for ax, column in zip(axes[0], columns, strict=False):
        order = np.argsort(table[column].to_numpy())
        x = table[column].to_numpy()[order]
        lo, hi = table["delta_q05"].to_numpy()[order], table["delta_q95"].to_numpy()[order]
        if len(columns) == 1:
            ax.fill_between(x, lo, hi, alpha=0.3, color="C2", label="delta, 90 %")
            ax.plot(x, table["delta_q50"].to_numpy()[order], color="C2")
        else:
            mid = table["delta_q50"].to_numpy()[order]
            ax.errorbar(x, mid, yerr=[mid - lo, hi - mid], fmt="o", ms=3, color="C2", label="delta, 90 %")
        ax.axhline(0, color="k", lw=0.8)
        ax.set_xlabel(column)
        ax.set_ylabel(f"discrepancy in {result.data.output}")
    axes[0][0].legend(fontsize=8)
    fig.suptitle("model discrepancy delta(x)")
    fig.tight_layout()
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


def plot_theta_functions(result: CalibrationResult, path: str | Path | None = None):
    """Each functional theta against each input it varies over: posterior
    mean and 90 % band (averaged over the other functional inputs)."""
    plt = pyplot()
    curves = result.theta_functions()
    inputs = list(result.options.functional_inputs)
    fig, axes = plt.subplots(len(curves), len(inputs), figsize=(5.5 * len(inputs), 3.6 * len(curves)),
                             squeeze=False)
    for row, (name, curve) in enumerate(curves.items()):
        table = pd.DataFrame({**curve["inputs"], "mean": curve["mean"], "q05": curve["q05"],
                              "q95": curve["q95"]})
        for ax, column in zip(axes[row], inputs, strict=False):
            along = table.groupby(column)[["mean", "q05", "q95"]].mean()
            ax.fill_between(along.index, along["q05"], along["q95"], alpha=0.3, color="C4",
                            label=f"{name}({column}), 90 %")
            ax.plot(along.index, along["mean"], color="C4")
            p = next(p for p in result.data.parameters if p.name == name)
            ax.set_ylim(p.lower, p.upper)
            ax.set_xlabel(column)
            ax.set_ylabel(name)
            ax.legend(fontsize=8)
    fig.suptitle("functional calibration parameters")
    fig.tight_layout()
    return finish(fig, path)


def finish(fig, path):
    """Save ``fig`` to ``path`` and close it; without a path, return it open."""
    if path is not None:
        fig.savefig(path, dpi=110)
        pyplot().close(fig)
    return fig


def write_plots(result: CalibrationResult, folder: str | Path) -> list[Path]:
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    paths = [folder / "theta.png", folder / "fit.png"]
    plot_theta(result, paths[0])
    plot_fit(result, paths[1])
    if result.options.discrepancy != "none":
        paths.append(folder / "discrepancy.png")
        plot_discrepancy(result, paths[-1])
    if result.options.functional:
        paths.append(folder / "theta_functions.png")
        plot_theta_functions(result, paths[-1])
    return paths


def plot_vector_curves(result, path: str | Path | None = None):
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
    columns = min(4, len(names))
    rows = -(-len(names) // columns)
    fig, axes = plt.subplots(rows, columns, figsize=(3.6 * columns, 2.9 * rows), squeeze=False, sharey=True)
    for e, (ax, name) in enumerate(zip(axes.ravel(), names, strict=False)):
        low, high = np.quantile(zeta[:, e], [0.05, 0.95], axis=0)
        ax.fill_between(along, low, high, color="C0", alpha=0.25, label="zeta, 90 %")
        ax.plot(along, f[:, e].mean(0), color="C1", lw=1.2, label="simulator f")
        measured = data.physical[data.physical[data.experiment] == name]
        ax.plot(measured[column], measured[data.output], "k.", ms=4, label="measured")
        ax.set_title(name, fontsize=9)
        ax.set_xlabel(column)
    for ax in axes.ravel()[len(names):]:
        ax.set_visible(False)
    axes[0][0].set_ylabel(data.output)
    axes[0][0].legend(fontsize=7)
    fig.tight_layout()
    return finish(fig, path)
