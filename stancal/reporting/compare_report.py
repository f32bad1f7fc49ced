"""The report of a method comparison: comparison.csv, comparison.json,
comparison.png and report.md."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pandas as pd

from stancal.diagnosing.compare import Comparison, discrepancy_rms
from stancal.diagnosing.scoring import PARETO_K_LIMIT
from stancal.reporting.html import write_html
from stancal.reporting.plots import finish, pyplot
from stancal.reporting.series import axis_label
from stancal.results.summaries import band


def plot_comparison(comparison: Comparison, path: str | Path | None = None,
                    units: dict[str, str] | None = None):
    """theta (median and 90 % interval) and discrepancy size per method,
    in the config's [units]."""
    from matplotlib.ticker import MaxNLocator

    plt = pyplot()
    fitted = [f for f in comparison.fits if f.result is not None]
    names = comparison.theta_names
    fig, axes = plt.subplots(1, len(names) + 1, figsize=(3.6 * (len(names) + 1), 0.5 * len(fitted) + 2),
                             layout="constrained")
    rows = range(len(fitted))
    for ax, name in zip(axes, names, strict=False):
        for i, fit in enumerate(fitted):
            s = fit.result.theta_summary()[name]
            ax.errorbar(s["q50"], i, xerr=[[s["q50"] - s["q05"]], [s["q95"] - s["q50"]]], fmt="o", capsize=3)
        ax.set_yticks(list(rows), [f.name for f in fitted])
        ax.set_xlabel(f"{axis_label(name, units)}\nmedian and 90 % interval")
    ax = axes[-1]
    for i, fit in enumerate(fitted):
        size = band(discrepancy_rms(fit.result, comparison.quadrature))
        q05, q50, q95 = size["q05"], size["q50"], size["q95"]
        ax.errorbar(q50, i, xerr=[[q50 - q05], [q95 - q50]], fmt="s", capsize=3, color="C3")
    ax.set_yticks(list(rows), [f.name for f in fitted])
    output = fitted[0].result.data.output if fitted else ""
    ax.set_xlabel(axis_label("discrepancy RMS over the input box", {"discrepancy RMS over the input box":
                                                                     (units or {}).get(output, "")})
                  + "\nmedian and 90 % interval")
    for ax in axes:  # a few ticks: theta's interval is narrow, and long tick labels run together
        ax.xaxis.set_major_locator(MaxNLocator(4))
    fig.suptitle("Calibration methods compared")
    return finish(fig, path)


def write_comparison(comparison: Comparison, folder: str | Path,
                     units: dict[str, str] | None = None) -> dict[str, Any]:
    """comparison.csv, comparison.json, comparison.png and report.md."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    table = comparison.table()
    table.to_csv(folder / "comparison.csv")
    summary = {"theta_names": comparison.theta_names,
               "methods": json.loads(table.reset_index().to_json(orient="records")),
               "quadrature_nodes": len(comparison.quadrature.weights)}
    (folder / "comparison.json").write_text(json.dumps(summary, indent=2))
    figure = folder / "comparison.png"
    plot_comparison(comparison, figure, units)
    (folder / "report.md").write_text(_report(table, figure))
    write_html(folder / "report.md")
    return summary


def _report(table: pd.DataFrame, figure: Path) -> str:
    return "\n".join([
        "# Calibration methods compared", "",
        "- **koh**: Kennedy & O'Hagan; theta's target depends on the discrepancy prior (review 6.1).",
        ("- **l2**: each posterior draw of zeta (from the koh fit) projected onto the simulator: "
        "theta = argmin ||zeta - f(., theta)||_L2 (Tuo & Wu 2015)."),
        ("- **orthogonal**: the discrepancy GP orthogonal to df/dtheta (Plumlee 2017): theta targets "
        "the L2 projection."),
        "- **scaled**: S-GaSP (Gu & Wang 2018): the discrepancy's mean square is penalised.",
        "", ("The discrepancy RMS is sqrt(mean over the input box of (zeta - f(x, theta))^2). "
        "ELPD is PSIS-LOO on the exact conditional likelihood; l2 shares koh's predictive model."), "",
        *unreliable_lines(table), table.round(4).to_markdown(), "", f"![comparison]({figure.name})", ""])


def unreliable_lines(table: pd.DataFrame) -> list[str]:
    """A line per method whose PSIS-LOO is unreliable (Pareto k above the
    limit of Vehtari et al. 2024): its ELPD is not to be trusted."""
    if "max_pareto_k" not in table:
        return []
    high = table["max_pareto_k"].dropna()
    high = high[high > PARETO_K_LIMIT]
    return [f"**{name}'s ELPD is unreliable**: Pareto k up to {k:.2f} > {PARETO_K_LIMIT} (the importance "
            "weights of some left-out points are too heavy-tailed); `stancal gap` refits such points." for
            name, k in high.items()] + ([""] if len(high) else [])
