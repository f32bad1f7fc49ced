"""The report of a simulation-based calibration (Talts et al. 2018;
Säilynoja et al. 2022): sbc.json and the ECDF differences of the ranks."""

from __future__ import annotations

import json
from pathlib import Path

from stancal.diagnosing.sbc import SBCResult
from stancal.reporting.plots import finish, pyplot


def write_sbc_report(result: SBCResult, folder: str | Path) -> Path:
    """sbc.json and ecdf.png (the ECDF difference of each parameter's
    fractional ranks, with its simultaneous band)."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "sbc.json").write_text(json.dumps(result.to_json(), indent=2))
    plt = pyplot()
    names = list(result.tests)
    columns = min(4, len(names))
    rows = -(-len(names) // columns)
    fig, axes = plt.subplots(rows, columns, figsize=(3.4 * columns, 2.8 * rows), squeeze=False, layout="constrained")
    for ax, name in zip(axes.ravel(), names, strict=False):
        test = result.tests[name]
        ax.fill_between(test.grid, *test.band, color="grey", alpha=0.3)
        ax.plot(test.grid, test.ecdf_difference, color="tab:red" if test.rejected else "tab:blue")
        ax.axhline(0, color="black", lw=0.8)
        ax.set_title(f"{name} (p = {test.p_value:.2g})", fontsize=8)
        ax.set_xlabel("fractional rank")
    for ax in axes.ravel()[len(names):]:
        ax.set_visible(False)
    axes[0][0].set_ylabel("ECDF - uniform")
    level = next(iter(result.tests.values())).level if result.tests else 0.95
    handles = [plt.Rectangle((0, 0), 1, 1, color="grey", alpha=0.3), plt.Line2D([], [], color="tab:blue"),
               plt.Line2D([], [], color="tab:red")]
    fig.legend(handles, [f"{level:.0%} simultaneous band of a uniform rank", "ranks consistent with uniform",
                         f"uniformity rejected (p < {1 - level:.2g})"], loc="outside lower center", ncol=3,
               fontsize=8)
    finish(fig, folder / "ecdf.png")
    return folder / "sbc.json"
