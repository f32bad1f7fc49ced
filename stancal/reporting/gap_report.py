"""The gap diagnosis for people: gap.json, figures, and report.md that
answers where, which and how far in words."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from stancal.diagnosing.gap import GapAnalysis
from stancal.diagnosing.gap_location import GapLocation
from stancal.diagnosing.scoring import CREDIBLE_SES
from stancal.reporting.html import write_html
from stancal.reporting.plots import LEVEL, finish, pyplot
from stancal.reporting.series import axis_label


def plot_importance(location: GapLocation, path: Path | None = None):
    """Total Sobol index of the discrepancy for each variable, with 90 % interval."""
    plt = pyplot()
    names = list(location.importance)
    est = [location.importance[v] for v in names]
    fig, ax = plt.subplots(figsize=(6.5, 0.5 * len(names) + 1.8), layout="constrained")
    y = np.arange(len(names))
    means = np.array([e["mean"] for e in est])
    ax.barh(y, means, color="tab:orange", alpha=0.7, label="posterior mean")
    ax.errorbar(means, y, xerr=[means - [e["q05"] for e in est], [e["q95"] for e in est] - means],
                fmt="none", color="black", capsize=3, label=f"{LEVEL} interval")
    ax.set_yticks(y, names)
    ax.invert_yaxis()
    ax.set_xlim(0, 1.05)
    ax.set_xlabel("total Sobol index: share of the discrepancy's variance\ninvolving the variable")
    ax.legend(fontsize=7, loc="lower right")
    ax.set_title("Where: what the gap depends on")
    return finish(fig, path)


def plot_main_effects(location: GapLocation, path: Path | None = None, units: dict[str, str] | None = None,
                      output: str | None = None):
    """E[delta | variable] with its 90 % band, one panel per variable (two or
    three to a row); shaded red where the band excludes 0."""
    plt = pyplot()
    effects = list(location.main_effects.values())
    columns = min(len(effects), 2 if len(effects) <= 4 else 3)
    rows = -(-len(effects) // columns)
    fig, axes = plt.subplots(rows, columns, figsize=(max(5.5, 4.2 * columns), 3.2 * rows + 0.5), squeeze=False,
                             sharey=True, layout="constrained")
    for ax, effect in zip(axes.ravel(), effects, strict=False):
        band = effect.band()
        if effect.categorical:
            x = np.arange(len(band))
            ax.errorbar(x, band["mean"], yerr=[band["mean"] - band.q05, band.q95 - band["mean"]],
                        fmt="o", capsize=4, color="C0")
            ax.set_xticks(x, [str(v) for v in band.value])
        else:
            ax.fill_between(band.value, band.q05, band.q95, alpha=0.3, color="C0", lw=0)
            ax.plot(band.value, band["mean"], color="C0")
            for region in effect.regions():
                ax.axvspan(region["from"], region["to"], color="tab:red", alpha=0.12, lw=0)
        ax.axhline(0, color="grey", lw=1)
        ax.set_xlabel(axis_label(effect.variable, units))
    for ax in axes.ravel()[len(effects):]:
        ax.set_visible(False)
    unit = (units or {}).get(output or "")
    for row in axes:
        row[0].set_ylabel("discrepancy\n(reality − simulator)" + (f" [{unit}]" if unit else ""))
    # one legend for every panel, with proxies
    axes[0][0].fill_between([], [], color="C0", alpha=0.3, lw=0, label=f"mean and {LEVEL} band")
    axes[0][0].axvspan(np.nan, np.nan, color="tab:red", alpha=0.12, label="band excludes 0")
    axes[0][0].legend(fontsize=7)
    fig.suptitle("Where: the discrepancy along each variable (the others averaged)", fontsize=10)
    return finish(fig, path)


def plot_candidates(summary: dict, path: Path | None = None):
    """ELPD difference and shrinkage of each candidate, best first."""
    plt = pyplot()
    cands = summary["candidates"]
    names = [c["name"] for c in cands]
    y = np.arange(len(cands))
    fig, (left, right) = plt.subplots(1, 2, figsize=(9, 0.5 * len(cands) + 1.8), sharey=True, layout="constrained")
    diff = np.array([c["elpd_diff"] for c in cands])
    left.errorbar(diff, y, xerr=2 * np.array([c["elpd_diff_se"] for c in cands]), fmt="o", capsize=3)
    left.axvline(0, color="grey", lw=1)
    left.set_xlabel("ELPD difference to baseline (± 2 se)")
    left.set_yticks(y, names)
    left.invert_yaxis()
    shrink = [c["shrinkage"] for c in cands]
    mean = np.array([s["mean"] for s in shrink])
    right.errorbar(mean, y, xerr=[mean - [s["q05"] for s in shrink], [s["q95"] for s in shrink] - mean],
                   fmt="o", capsize=3, color="tab:green")
    right.axvline(0, color="grey", lw=1)
    right.set_xlabel(f"shrinkage of the remaining discrepancy ({LEVEL})")
    fig.suptitle("Which effect, and how far the gap shrinks")
    return finish(fig, path)


def _value(v) -> str:
    return f"{v:.4g}" if isinstance(v, float) else str(v)


def _fmt(est: dict) -> str:
    return f"{est['mean']:.3g} [{est['q05']:.3g}, {est['q95']:.3g}]"


def _along_index(where: dict, ranked: list) -> list[str]:
    """A vector output: where along its index the gap sits, with the most
    important other variable held low and high."""
    conditions = where.get("along_index", [])
    given = next((name for name, _ in ranked if any(c["given"] == name for c in conditions)), None)
    if given is None:
        return []
    lines = ["", f"Along the output index, with **{given}** held low and high (the others averaged):", ""]
    for c in (c for c in conditions if c["given"] == given):
        spans = "; ".join(f"{r['from']:.4g} to {r['to']:.4g} ({r['sign']})" for r in c["regions"])
        lines.append(f"- {given} = {c['value']:.4g} ({c['level']}): "
                     + (f"{c['index']} from {spans}" if spans else f"nowhere along {c['index']} credibly non-zero"))
    return lines


def _where_section(summary: dict) -> list[str]:
    """The report's opening and its answer to 'where is the simulator wrong?'."""
    base, where = summary["baseline"], summary["where"]
    ranked = sorted(where["importance"].items(), key=lambda kv: -kv[1]["mean"])
    lines = ["# Sim-to-real gap", "",
             (f"Baseline: {base['method']} with a GP discrepancy over "
             f"{', '.join(where['importance'])}, in {base['discrepancy_scale']}. Remaining "
             f"discrepancy (RMS over the physical points): {_fmt(base['discrepancy_rms'])}; "
             f"held-out RMSE {base['holdout_rmse']:.4g} "
             f"({base['scheme']})."), "",
             "## Where is the simulator wrong?", "",
             f"The gap depends most on **{ranked[0][0]}** (total Sobol index {_fmt(ranked[0][1])})"
             + (f", then {ranked[1][0]} ({_fmt(ranked[1][1])})." if len(ranked) > 1 else "."),
             (f"At {where['observations_with_credible_gap']} physical points the discrepancy's 90 % "
             "interval excludes zero. (Sobol indices are estimated per posterior draw by Monte "
             "Carlo and clipped to [0, 1], the range of a Sobol index.)"), ""]
    local = [r for r in where["regions"] if not r["whole_range"]]
    everywhere = sorted({r["variable"] for r in where["regions"] if r["whole_range"]})
    if local:
        lines += [("Ranges where the discrepancy, averaged over the other variables, is credibly "
                  "non-zero:"), "", "| variable | from | to | direction |", "|---|---|---|---|",
                  *(f"| {r['variable']} | {_value(r['from'])} | {_value(r['to'])} | {r['sign']} |"
                    for r in local)]
    else:
        lines += [("No part of any variable's range where the averaged discrepancy is credibly "
                  "non-zero while it is not elsewhere.")]
    if everywhere:
        lines += ["", (f"Along {', '.join(everywhere)} the averaged discrepancy is credibly non-zero "
                  "over the whole range: the gap is there whatever their value.")]
    lines += _along_index(where, ranked)
    return lines


def _which_section(base: dict, cands: list[dict], level: str = "a constant in the discrepancy's mean"
                   ) -> list[str]:
    """The best candidate, its shrinkage of the gap and the table of all
    candidates; ``level``: what carries the discrepancy's level in every fit."""
    if not cands:
        return []
    best = cands[0]
    moved = ", ".join(f"{k} {base['theta'][k]['mean']:.4g} → {best['theta'][k]['mean']:.4g}"
                      for k in best["theta_change"])
    credible = best["elpd_diff"] > CREDIBLE_SES * best["elpd_diff_se"]
    return [
        f"Best candidate: **{best['name']}** ({best['kind']}: `{best['effect']}`), ELPD "
        f"{best['elpd_diff']:+.1f} ± {best['elpd_diff_se']:.1f} over the baseline"
        + (" (more than 2 se: credible)." if credible else " (within 2 se: not decisive)."),
        (f"With it, the remaining discrepancy varies over the physical points by "
        f"{_fmt(best['discrepancy_variation'])} (RMS about its mean; baseline "
        f"{_fmt(base['discrepancy_variation'])}): shrinkage {_fmt(best['shrinkage'])}. "
        f"θ moves: {moved}. Held-out RMSE {base['holdout_rmse']:.4g} → {best['holdout_rmse']:.4g}."), "",
        ("Shrinkage is 1 − (variation with the candidate) / (variation of the baseline). It "
        f"leaves out the discrepancy's level: every fit has {level}, and a term that is "
        "nearly constant over the points trades its level with it, so only the variation is "
        "identified."), "",

        "| candidate | kind | ELPD diff ± se | shrinkage (90 %) | remaining RMS | θ | held-out RMSE |",
        "|---|---|---|---|---|---|---|",
        *(f"| {c['name']} | {c['kind']} | {c['elpd_diff']:+.1f} ± {c['elpd_diff_se']:.1f} | "
          f"{_fmt(c['shrinkage'])} | {_fmt(c['discrepancy_rms'])} | "
          + "; ".join(f"{k} {_fmt(v)}" for k, v in c["theta"].items())
          + f" | {c['holdout_rmse']:.4g} |" for c in cands)]


def report_markdown(summary: dict, figures: list[Path]) -> str:
    base, cands = summary["baseline"], summary["candidates"]
    carriers = [c["theta"] for c in summary.get("confounding", []) if c["dropped"]]
    lines = [*_where_section(summary), "", "## Which effect explains it, and how far does the gap shrink?", ""]
    if summary.get("confounding"):  # found before sampling (stancal.fitting.confounding): said first
        lines += ["Before sampling: " + "; ".join(c["message"] for c in summary["confounding"]) + ".", ""]
    level = f"{' and '.join(carriers)} carrying the level (no constant in the discrepancy's mean)"
    lines += _which_section(base, cands, level) if carriers else _which_section(base, cands)
    if summary.get("failed"):
        lines += ["", "Left out, their fit having failed twice: "
                  + "; ".join(f"{f['name']} ({f['error']})" for f in summary["failed"]) + "."]
    timing = summary.get("timing", {})
    if timing:
        lines += ["", "Time: " + ", ".join(f"{stage} {seconds:.0f} s" for stage, seconds in timing.items())
                  + f" (refits: {base['refits'] + sum(c['refits'] for c in cands)} fits)."]
    warned = [(c["name"], w) for c in [{"name": "baseline", **base}, *cands]
              for w in c["diagnostics"].get("warnings", [])]
    if warned:
        lines += ["", "## Sampler warnings", "", *(f"- {name}: {w}" for name, w in warned)]
    lines += ["", "## Figures", "", *(f"![{p.stem}]({p.name})" for p in figures), ""]
    return "\n".join(lines)


def write_gap_report(analysis: GapAnalysis, folder: str | Path, units: dict[str, str] | None = None) -> dict:
    """gap.json, importance.png, where.png, candidates.png, report.md and
    report.html. ``units``: name -> unit for the figures' axes."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    summary = analysis.to_json()
    (folder / "gap.json").write_text(json.dumps(summary, indent=2))
    figures = [folder / "importance.png", folder / "where.png"]
    plot_importance(analysis.location, figures[0])
    plot_main_effects(analysis.location, figures[1], units, analysis.baseline.data.output)
    if summary["candidates"]:
        figures.append(folder / "candidates.png")
        plot_candidates(summary, figures[-1])
    (folder / "report.md").write_text(report_markdown(summary, figures))
    write_html(folder / "report.md")
    return summary
