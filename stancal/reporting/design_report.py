"""The design folder of `stancal design`: next_runs.csv, nroy.csv,
design.json, waves.json (every wave's cut, read by the next wave),
next_experiments.csv with --experiments, figures and report.md. The whole
folder is made as a temporary folder beside the target (with any files of
the user's the target held, hard-linked) and then renamed onto it: the
target is renamed aside, the new folder renamed in, and the old one
removed (put back should the rename in fail). A failure while the files
are made (the fits, the figures) or moved leaves the folder as it was,
never half-written; only a crash between the two renames, a moment, leaves
the old folder beside it under a hidden name, whole."""

from __future__ import annotations

import json
import os
import shutil
import tempfile
import uuid
from pathlib import Path

import numpy as np

from stancal.designing.implausibility import combined
from stancal.designing.loop import Design
from stancal.designing.targets import run_table
from stancal.reporting.html import write_html
from stancal.reporting.plots import finish, pyplot
from stancal.reporting.series import axis_label

BINS = 20  # per axis of the pairs plot
UNIFORM_POINTS = 20000  # the uniform sample the minimum implausibility is taken over (with the NROY sample)
MAX_PAIRS_COLUMNS = 8
BACKGROUND_POINTS = 600  # NROY draws behind the runs in proposed_runs.png (enough to show its shape)


def pairs_grid(design: Design, seed: int = 0) -> dict:
    """hmer's two summaries of NROY over each pair of theta, on a BINS x BINS grid
    of their unit square: the minimum implausibility over the other theta
    (over a uniform sample and the NROY sample), and the optical depth, the
    share of the other theta's box not ruled out, P(NROY | bin) =
    fraction x P(bin | NROY) / P(bin), from the NROY sample (so it stays
    resolved when NROY is a tiny part of the box). Each grid only for the
    panels that show it: ``minimum[i, j]`` for j > i, ``depth[j, i]``."""
    match = design.match
    Q = len(match.box.nroy_names)
    uniform = np.random.default_rng(seed).uniform(size=(UNIFORM_POINTS, Q))
    points = np.vstack([uniform, match.nroy.theta_unit])
    value = np.concatenate([combined(match.cuts, uniform), match.nroy.implausibility])
    cells = np.minimum((points * BINS).astype(int), BINS - 1)
    nroy_cells = cells[UNIFORM_POINTS:]
    minimum, depth = {}, {}
    for i in range(min(Q, MAX_PAIRS_COLUMNS)):
        for j in range(i + 1, min(Q, MAX_PAIRS_COLUMNS)):  # each grid for its own triangle only
            grid = np.full((BINS, BINS), np.nan)
            np.fmin.at(grid, (cells[:, j], cells[:, i]), value)
            minimum[i, j] = grid
            counts = np.zeros((BINS, BINS))
            np.add.at(counts, (nroy_cells[:, i], nroy_cells[:, j]), 1.0)
            # an estimate, so it can pass 1 where NROY fills a bin: a share is at most 1
            depth[j, i] = np.minimum(match.nroy_fraction * counts / len(nroy_cells) * BINS**2, 1.0)
    return {"minimum": minimum, "depth": depth}


def plot_nroy_pairs(design: Design, path: Path | None = None, units: dict[str, str] | None = None):
    """Lower triangle: minimum implausibility (the cutoff marked in the
    colour bar); upper: optical depth; diagonal: theta's NROY histogram."""
    match = design.match
    if len(match.box.nroy_names) == 1:
        return plot_nroy_line(design, path, units)
    plt = pyplot()
    from matplotlib.colors import LinearSegmentedColormap, LogNorm

    names = match.box.nroy_names[:MAX_PAIRS_COLUMNS]  # the first theta (shared, then the first experiments')
    Q = len(names)
    low, width = (bound[:Q] for bound in match.box.nroy_bounds())
    grids = pairs_grid(design)
    cutoff = match.cutoff
    top = max(2 * cutoff, float(np.nanmax([np.nanmax(g) for g in grids["minimum"].values()] or [cutoff])))
    top = min(top, 4 * cutoff)
    implausibility_map = LinearSegmentedColormap.from_list(
        "implausibility", [(0, "#1a9641"), (cutoff / top, "#ffffbf"), (1, "#d7191c")])
    depth_values = np.concatenate([g[g > 0] for g in grids["depth"].values()] or [np.array([1.0])])
    depth_norm = LogNorm(vmin=min(max(depth_values.min(), 1e-6), 0.1), vmax=1.0)
    size = max(2.3 * Q, 5.0)
    fig, axes = plt.subplots(Q, Q, figsize=(size + 2.5, size), squeeze=False, layout="constrained")
    extent = lambda i, j: (low[i], low[i] + width[i], low[j], low[j] + width[j])  # noqa: E731
    image_min = image_depth = None
    nroy = match.nroy_frame()
    for i in range(Q):
        for j in range(Q):
            ax = axes[j, i]
            if i == j:
                ax.hist(nroy[names[i]], bins=BINS, range=(low[i], low[i] + width[i]), color="tab:green", alpha=0.7)
                ax.set_yticks([])
            elif j > i:
                image_min = ax.imshow(np.clip(grids["minimum"][i, j], 0, top), origin="lower", aspect="auto",
                                      extent=extent(i, j), cmap=implausibility_map, vmin=0, vmax=top)
            else:
                grid = np.where(grids["depth"][i, j] > 0, grids["depth"][i, j], np.nan)
                image_depth = ax.imshow(grid, origin="lower", aspect="auto", extent=extent(i, j), cmap="viridis",
                                        norm=depth_norm)
            ax.set_xlabel(axis_label(names[i], units), fontsize=8)
            ax.set_ylabel("NROY draws" if i == j else axis_label(names[j], units), fontsize=8)
            ax.tick_params(labelsize=7)
    if image_min is not None:
        bar = fig.colorbar(image_min, ax=axes, location="right", shrink=0.6, pad=0.01)
        bar.set_label(f"minimum implausibility, lower triangle\n(line: the cutoff {cutoff:g})", fontsize=8)
        bar.ax.axhline(cutoff, color="black", linewidth=1.5)
        depth_bar = fig.colorbar(image_depth, ax=axes, location="right", shrink=0.6, pad=0.01)
        depth_bar.set_label("optical depth, upper triangle: share of\nthe other theta not ruled out", fontsize=8)
    fig.suptitle(f"NROY after wave {len(match.waves)}: {match.nroy_fraction:.3g} of theta's box\n"
                 f"(diagonal: each theta's histogram over NROY)", fontsize=10)
    return finish(fig, path)


def plot_nroy_line(design: Design, path: Path | None = None, units: dict[str, str] | None = None):
    """One theta: the implausibility over its range (every wave's cut
    combined), the cutoff, and NROY shaded."""
    plt = pyplot()
    match = design.match
    unit = np.linspace(0, 1, 801)[:, None]
    value = combined(match.cuts, unit)
    theta = match.box.theta_to_original(unit)[:, 0]
    fig, ax = plt.subplots(figsize=(6, 3.8), layout="constrained")
    ax.plot(theta, value, color="black", label="implausibility (every wave's cut)")
    ax.axhline(match.cutoff, color="tab:red", linestyle="--", label=f"cutoff {match.cutoff:g}")
    ax.fill_between(theta, 0, 1, where=value <= match.cutoff, transform=ax.get_xaxis_transform(),
                    color="tab:green", alpha=0.2, label="NROY")
    ax.set_ylim(0, min(float(value.max()) * 1.05, 5 * match.cutoff))
    ax.set_xlabel(axis_label(match.box.nroy_names[0], units))
    ax.set_ylabel("implausibility (sd)")
    ax.legend(fontsize=8)
    ax.set_title(f"NROY after wave {len(match.waves)}: {match.nroy_fraction:.3g} of theta's range", fontsize=10)
    return finish(fig, path)


def plot_fraction_by_wave(design: Design, path: Path | None = None):
    """NROY's share of theta's box after each wave, log scale, with the
    estimate's coefficient of variation as an error bar."""
    plt = pyplot()
    waves = design.match.waves
    number = [w.number for w in waves]
    fraction = np.array([w.nroy_fraction for w in waves])
    cv = np.array([w.nroy_fraction_cv for w in waves])
    fig, ax = plt.subplots(figsize=(5.5, 3.8), layout="constrained")
    ax.errorbar(number, fraction, yerr=fraction * cv, marker="o", capsize=3, color="tab:blue",
                label="NROY fraction (bar: ±1 sd for independent samples)")
    ax.set_yscale("log")
    ax.set_xticks(number)
    ax.set_xlabel("wave")
    ax.set_ylabel("NROY share of theta's box")
    for n, f, w in zip(number, fraction, waves, strict=True):
        ax.annotate(f"{f:.2g}\n{w.runs_total} runs", (n, f), textcoords="offset points", xytext=(6, 4), fontsize=7)
    ax.legend(fontsize=7)
    ax.set_title("NROY by wave")
    return finish(fig, path)


def plot_proposed_runs(design: Design, path: Path | None = None, units: dict[str, str] | None = None):
    """Pairs of the runs' columns (inputs and theta): NROY x the inputs'
    range (the NROY sample, each draw at uniform inputs), the existing runs
    and the proposed ones."""
    plt = pyplot()
    box = design.match.box
    columns = box.columns[:MAX_PAIRS_COLUMNS]
    existing = box.to_original(run_table(design.match.data, box)[0])
    proposed = design.next_runs[box.columns].to_numpy(float)
    nroy = design.match.nroy.theta_unit[:BACKGROUND_POINTS]  # a uniform sample: its first rows are one too
    rng = np.random.default_rng(0)
    spread = np.column_stack([rng.uniform(size=(len(nroy), len(box.inputs))), box.run_theta(nroy, rng)])
    background = box.to_original(spread)
    C = len(columns)
    panel = 2.4 if C <= 4 else 1.7  # inches: many columns make small panels
    fig, axes = plt.subplots(C - 1, C - 1, figsize=(panel * (C - 1) + 1.2, panel * (C - 1) + 0.8), squeeze=False,
                             layout="constrained")
    for row in range(1, C):
        for col in range(C - 1):
            ax = axes[row - 1, col]
            if col >= row:
                ax.axis("off")
                continue
            ax.scatter(background[:, col], background[:, row], s=2, color="0.8", label="NROY x inputs' range")
            ax.scatter(existing[:, col], existing[:, row], s=10, color="tab:blue", label="existing runs")
            ax.scatter(proposed[:, col], proposed[:, row], s=28, marker="x", color="tab:red", label="proposed runs")
            ax.set_xlim(box.low[col], box.low[col] + box.width[col])
            ax.set_ylim(box.low[row], box.low[row] + box.width[row])
            ax.set_xlabel(axis_label(columns[col], units), fontsize=8)
            ax.set_ylabel(axis_label(columns[row], units), fontsize=8)
            ax.tick_params(labelsize=7)
    handles, labels = axes[-1, 0].get_legend_handles_labels()
    if C > 2:
        axes[0, -1].legend(handles, labels, loc="upper right", fontsize=8, markerscale=1.5)
    else:
        axes[0, 0].legend(fontsize=7, loc="best")
    fig.suptitle(f"{len(proposed)} proposed runs ({design.criterion} criterion), {len(existing)} existing\n"
                 f"inputs over the physical data's range, theta over its bounds", fontsize=10)
    return finish(fig, path)


def report_markdown(summary: dict, figures: list[Path]) -> str:
    waves = summary["waves"]
    lines = [f"# Design: wave {len(waves)}", "",
             (f"- NROY: {summary['nroy_fraction']:.3g} of theta's box (coefficient of variation "
             f"{summary['nroy_fraction_cv']:.2f}); cutoff {summary['cutoff']:g} on the "
             f"{_ordinal(summary['nth_maximum'])} largest implausibility over {summary['observations']} observations"),
             f"- noise sd {summary['noise_sd']:.4g}: {summary['noise_sd_source']}",
             f"- discrepancy sd {summary['discrepancy_sd']:.4g}: {summary['discrepancy_sd_source']}",
             f"- {summary['runs']} runs so far; {summary['proposed_runs']} proposed in next_runs.csv by the "
             f"`{summary['criterion']}` criterion"
             + (f" (posterior from `{summary['posterior_method']}`)" if "posterior_method" in summary else ""),
             *([(f"- theta's posterior for the criterion: {d['divergences']} divergences, max R-hat "
                f"{d['max_rhat']:.3f}, min bulk ESS {d['min_ess_bulk']:.0f}")]
               if (d := summary.get("posterior_diagnostics")) else []),
             *([f"- {summary['proposed_experiments']} physical settings in next_experiments.csv"]
               if summary["proposed_experiments"] else []),
             "", "## Waves", "", "| wave | runs | emulator runs | refocused | NROY fraction |", "|---|---|---|---|---|",
             *(f"| {w['number']} | {w['runs_total']} | {w['runs_used']} | {'yes' if w['refocused'] else 'no'} | "
               f"{w['nroy_fraction']:.3g} |" for w in waves),
             "", ("Run the simulator at next_runs.csv, append the results to the runs CSV and run `stancal design` "
             "with the same --out folder again for the next wave."),
             "", "## Figures", "", *(f"![{p.stem}]({p.name})" for p in figures), ""]
    return "\n".join(lines)


def _ordinal(n: int) -> str:
    return {1: "1st", 2: "2nd", 3: "3rd"}[n]


DESIGN_FILES = frozenset({"next_runs.csv", "nroy.csv", "next_experiments.csv", "design.json", "waves.json",
                          "nroy_pairs.png", "nroy_by_wave.png", "proposed_runs.png", "report.md", "report.html"})


def write_design(design: Design, folder: str | Path, units: dict[str, str] | None = None) -> dict:
    """Every file of a design folder, made in a folder beside it and renamed onto it (see the module)."""
    folder = Path(folder)
    folder.parent.mkdir(parents=True, exist_ok=True)
    summary = design.to_json()
    staging = folder.parent / f".{folder.name}.{uuid.uuid4().hex}"
    staging.mkdir()  # not mkdtemp: a new folder's default mode, not a private one
    try:
        keep_users_files(folder, staging)
        write_files(design, summary, staging, units)
        swap_in(staging, folder)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return summary


def keep_users_files(folder: Path, staging: Path) -> None:
    """``staging`` with the mode of ``folder``, if there is one, and,
    hard-linked, the files in it that are not the design's (an earlier
    wave's design files are replaced, or dropped: its next_experiments.csv
    would read as this wave's)."""
    if not folder.is_dir():
        return
    shutil.copymode(folder, staging)
    for path in folder.iterdir():
        if path.name in DESIGN_FILES:
            continue
        if path.is_dir():
            shutil.copytree(path, staging / path.name, copy_function=os.link)
        else:
            os.link(path, staging / path.name)


def swap_in(staging: Path, folder: Path) -> None:
    """``staging`` renamed onto ``folder``: the old folder renamed aside
    first (put back if the rename in fails), then removed."""
    if not folder.exists():
        os.rename(staging, folder)
        return
    aside = Path(tempfile.mkdtemp(prefix=f".{folder.name}.old.", dir=folder.parent))
    os.rename(folder, aside / folder.name)
    try:
        os.rename(staging, folder)
    except BaseException:
        os.rename(aside / folder.name, folder)
        raise
    finally:
        if folder.exists():
            shutil.rmtree(aside, ignore_errors=True)


def write_files(design: Design, summary: dict, staging: Path, units: dict[str, str] | None) -> None:
    """The design's files in ``staging``."""
    design.next_runs.to_csv(staging / "next_runs.csv", index=False)
    design.match.nroy_frame().to_csv(staging / "nroy.csv", index=False)
    if design.next_experiments is not None:
        design.next_experiments.to_csv(staging / "next_experiments.csv", index=False)
    (staging / "design.json").write_text(json.dumps(summary, indent=2))
    (staging / "waves.json").write_text(json.dumps({"box": design.match.box.to_dict(),
                                                    "waves": [w.to_dict() for w in design.match.waves]}))
    figures = [staging / "nroy_pairs.png", staging / "nroy_by_wave.png", staging / "proposed_runs.png"]
    plot_nroy_pairs(design, figures[0], units)
    plot_fraction_by_wave(design, figures[1])
    plot_proposed_runs(design, figures[2], units)
    (staging / "report.md").write_text(report_markdown(summary, figures))
    write_html(staging / "report.md")
