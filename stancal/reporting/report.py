"""The report folder of one calibration: summary.json, summary.csv, figures
and report.md. The command line and the case studies write it through here."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from stancal.problem.noise import HETEROSCEDASTIC
from stancal.problem.run_replicates import describe
from stancal.reporting.html import write_html
from stancal.results.vector_result import VectorCalibrationResult


def write_calibration(result, folder: str | Path, warning_messages: list[str] | None = None,
                      units: dict[str, str] | None = None) -> dict:
    """summary.json, summary.csv, figures, report.md and report.html of one
    calibration, in ``folder`` (made if missing). A vector-output result gets
    its curves instead of the scalar figures.

    ``warning_messages`` are the warnings the report lists: by default the
    sampler's checks recorded on the result (``result.diagnostics.messages``);
    the command line passes every stancal warning the fit raised.
    ``units``: name -> unit for the figures' axes (the config's [units])."""
    from stancal.reporting.plots import write_plots

    if isinstance(result, VectorCalibrationResult):
        return write_vector_calibration(result, folder, warning_messages, units)
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    summary = result.to_summary_json()
    summary["warnings"] = _recorded(result) if warning_messages is None else list(warning_messages)
    (folder / "summary.json").write_text(json.dumps(summary, indent=2))
    result.summary().to_csv(folder / "summary.csv")
    plots = write_plots(result, folder, units)
    (folder / "report.md").write_text(_report(summary, result.summary(), plots))
    write_html(folder / "report.md")
    return summary


def _recorded(result) -> list[str]:
    """The sampler's warnings kept on the result (none for a result without checks)."""
    return list(result.diagnostics.messages) if result.diagnostics else []


def stage_times(timing: dict) -> str:
    """The fit's stage times in words: its compile (or that the program was
    compiled earlier, by another command or an earlier step), then sampling
    (stage 1 included, and loading the program with the data)."""
    compiled = (f"compile {timing['compile_s']:.1f} s" if timing["compile_s"] > 0
                else "compiled earlier (the program came from the cache)")
    return f"{compiled}, sampling {timing['sample_s']:.1f} s"


def _parameters_and_sampler(summary: dict, table) -> list[str]:
    """The report's theta table, every parameter, and the sampler's figures
    and warnings: the same for every kind of calibration."""
    d = summary["diagnostics"]
    return [
        "## Calibration parameters (original units; 90 % interval)", "",
        "| parameter | mean | 5 % | 50 % | 95 % | R-hat | bulk ESS |", "|---|---|---|---|---|---|---|",
        *(f"| {k} | {v['mean']:.4g} | {v['q05']:.4g} | {v['q50']:.4g} | {v['q95']:.4g} | "
          f"{v['rhat']:.3f} | {v['ess_bulk']:.0f} |"
          for k, v in [*summary["theta"].items(), *summary.get("theta_low", {}).items()]),
        "", "## All parameters", "", table.round(4).to_markdown(),
        "", "## Sampler", "",
        (f"- divergences: {d['divergences']}; max R-hat {d['max_rhat']:.3f}; "
        f"min bulk ESS {d['min_ess_bulk']:.0f}; min tail ESS {d['min_ess_tail']:.0f}"),
        f"- {stage_times(summary['timing'])}",
        *parametrization_line(summary),
        *(f"- **warning**: {w}" for w in summary.get("warnings", [])),
    ]


def parametrization_line(summary: dict) -> list[str]:
    """How the latent discrepancy GP was sampled, and why (the plan's choice,
    and the refit the other way if the first fit saturated the tree depth)."""
    reason = summary.get("options", {}).get("discrepancy_parametrization_reason")
    return [f"- the discrepancy's latent GP was sampled {reason}"] if reason else []


def fidelity_lines(emulator: dict) -> list[str]:
    """What the cheaper simulators' runs gave the emulator (stancal.numerics.multifidelity)."""
    if "level_rho" not in emulator:
        return []
    return ["", "## Emulator of several fidelities (Kennedy & O'Hagan 2000)", "",
            f"- {emulator['stage1']}",
            *rho_lines(emulator),
            (f"- leave-one-out error at the calibrated simulator's runs: {emulator['loo_rmse']:.3g} with the "
             f"cheaper runs, {emulator['loo_rmse_without_low_fidelity']:.3g} without (standardised units)"),
            *([(f"- the calibrated simulator's own GP: its variance times "
                f"{emulator['top_level_variance_factor']:.3g} for its hyperparameters' uncertainty "
                "(docs/multifidelity.md)")] if "top_level_variance_factor" in emulator else []),
            *([f"- **warning**: {emulator['warning']}"] if emulator.get("warning") else [])]


def rho_lines(emulator: dict) -> list[str]:
    """Each level's scale on the one below: a number, or a linear rho(x)'s
    coefficients, range and profile along each input (Le Gratiet & Garnier 2014)."""
    if "level_rho_slope" not in emulator:
        where = (" at stage 1 (the chains' start: the fit samples it, level_rho in the posterior)"
                 if emulator.get("rho_sampled") else "")
        values = ", ".join(f"{r:.3g}" for r in emulator["level_rho"])
        return [f"- each level's scale on the one below{where}: {values}"]
    lines = []
    for k, (rho, slopes, (low, high), profile) in enumerate(zip(
            emulator["level_rho"], emulator["level_rho_slope"], emulator["level_rho_range"],
            emulator["level_rho_profile"], strict=True), start=2):
        terms = " ".join(f"{b:+.3g} u_{name}" for name, b in slopes.items())
        lines += [(f"- level {k}'s scale on the one below, linear in the inputs: rho(x) = {rho:.3g} {terms} "
                   f"(u: each input on [0, 1] over its range), from {low:.3g} to {high:.3g} over the inputs' box"),
                  "", "  | along | the input at | rho there (the other inputs at their centre) |", "  |---|---|---|"]
        lines += [(f"  | {name} | {', '.join(f'{v:.3g}' for v in values)} | "
                   f"{', '.join(f'{r:.3g}' for r in profile['rho'][name])} |")
                  for name, values in profile["inputs"].items()]
        lines.append("")
    return lines


def replicated_run_lines(emulator: dict) -> list[str]:
    """The simulator's replicated runs, and a stochastic simulator's
    intrinsic sd (stancal.fitting.run_variance; docs/noise.md)."""
    runs = emulator.get("replicated_runs")
    if not runs or not runs["replicated_settings"]:
        return []
    lines = ["", "## Replicated simulator runs", "", f"- {describe(runs)} (output units)"]
    if runs["stochastic"]:
        low, high = runs["intrinsic_sd_range"]
        lines.append(f"- stochastic simulator: the emulator of its mean carries its own sd, {low:.3g} to {high:.3g} "
                     f"at the replicated settings ({runs['intrinsic_variance_model']}), on the runs only")
    return lines


def noise_lines(noise: dict, table) -> list[str]:
    """The noise model, each source's sd and nu (docs/noise.md), and the rows
    a Student-t fit treats as outliers, by its stated rule."""
    lines = [f"- model: {noise['model']}" + (f"; known sd per row from column '{noise['known_sd_column']}', "
                                             "added in quadrature" if noise["known_sd_column"] else "")]
    table = table[~table.index.duplicated()]  # several theta modes: the noise rows of the first
    sds = [p for p in table.index if str(p).startswith("noise_sd") or p == "nu"]
    lines += [f"- {p}: {table.loc[p, 'mean']:.4g} [{table.loc[p, 'q05']:.4g}, {table.loc[p, 'q95']:.4g}]"
              for p in sds]
    if noise["model"] == "per_source" or noise.get("biased_sources"):
        lines.append("- rows per source (column '{}'): {}".format(
            noise["source_column"], ", ".join(f"{k} {v}" for k, v in noise["rows_per_source"].items())))
    if noise.get("biased_sources"):
        lines += source_bias_lines(noise, table)
    if noise["model"] == HETEROSCEDASTIC:
        lines += heteroscedastic_lines(noise)
    if noise["model"] == "student_t":
        rows = noise["outliers"]
        lines.append(f"- outliers ({noise['outlier_rule']}): " + (", ".join(
            f"row {r['row']} (weight {r['weight']:.2f})" for r in rows) if rows else "none"))
    return lines


def source_bias_lines(noise: dict, table) -> list[str]:
    """The biased sources, the references, and each bias GP's hyperparameters
    (output and input units; the curves and their bands: source_bias.png)."""
    rows = [p for p in table.index if str(p).startswith(("bias_sd", "bias_length_scale"))]
    return [(f"- biased sources, each with a bias GP over the simulator inputs beside the discrepancy: "
             f"{', '.join(noise['biased_sources'])}; references (the discrepancy alone): "
             f"{', '.join(noise['reference_sources'])}"),
            *(f"- {p}: {table.loc[p, 'mean']:.4g} [{table.loc[p, 'q05']:.4g}, {table.loc[p, 'q95']:.4g}]"
              for p in rows),
            f"- each bias curve with its {noise['bias_band']} band: source_bias.png"]


def heteroscedastic_lines(noise: dict) -> list[str]:
    """The replicates found and the noise sd curve's range (the curve and its band: noise_sd.png)."""
    r, curve = noise["replicates"], noise["sd_curve"]
    low, high = int(np.argmin(curve["mean"])), int(np.argmax(curve["mean"]))

    def at(i: int) -> str:  # the setting, every noise input's value
        return ", ".join(f"{c} = {curve[c][i]:.4g}" for c in noise["noise_inputs"])
    return [(f"- the log noise sd is a GP over {', '.join(noise['noise_inputs'])} "
             "(noise_sd: the sd's geometric mean over the settings)"),
            (f"- replicates: {r['replicate_rows']} of {r['rows']} rows repeat another row's inputs "
             f"({r['replicated_settings']} of {r['settings']} settings measured more than once)"),
            (f"- noise sd from {curve['mean'][low]:.4g} [{curve['q05'][low]:.4g}, {curve['q95'][low]:.4g}] "
             f"at {at(low)} to {curve['mean'][high]:.4g} "
             f"[{curve['q05'][high]:.4g}, {curve['q95'][high]:.4g}] at {at(high)} "
             f"(posterior mean, {noise['band']} band; the curve: noise_sd.png, summary.json noise.sd_curve)")]


def _report(summary: dict, table, plots: list[Path]) -> str:
    lines = [
        (f"# Calibration report ({summary['method']}, {summary['backend']}, "
        f"{summary['likelihood']} likelihood)"), "",
        *_parameters_and_sampler(summary, table),
    ]
    if summary.get("confounding"):  # found before sampling (stancal.fitting.confounding)
        lines += ["", "## Before sampling: theta against the model's own terms", "",
                  *(f"- {c['message']}" for c in summary["confounding"])]
    lines += fidelity_lines(summary.get("emulator", {}))
    lines += replicated_run_lines(summary.get("emulator", {}))
    if "noise" in summary:
        lines += ["", "## Measurement noise", "", *noise_lines(summary["noise"], table)]
    if "censoring" in summary:
        counts = summary["censoring"]
        lines += ["", "## Censored observations", "",
                  (f"- exact {counts['observed']}, left-censored {counts['left']}, "
                  f"right-censored {counts['right']}, interval-censored {counts['interval']}")]
    for name, curve in summary.get("theta_functions", {}).items():
        column = next(iter(curve["inputs"]))
        lines += ["", f"## Functional parameter {name}({', '.join(curve['inputs'])})", "",
                  (f"- over {column} from {min(curve['inputs'][column]):.4g} to {max(curve['inputs'][column]):.4g}: "
                  f"posterior mean from {min(curve['mean']):.4g} to {max(curve['mean']):.4g}; "
                  "the grid and its 90 % band are in summary.json (theta_functions)")]
    if len(summary["modes"]) > 1:
        weighed = summary["modes"][0]["weight"] is not None
        lines += ["", "## Separate theta modes", "",
                  ("The theta table above is the mixture of the modes, each weighted by its posterior "
                   "mass (bridge sampling; 90 % Monte Carlo interval of the weight)." if weighed else
                   "Their posterior masses are unknown: the theta table above is the mode with the "
                   "highest log density."), "",
                  *(f"- mode {i + 1}: chains {m['chains']}, "
                    + (f"weight {m['weight']['mean']:.3f} [{m['weight']['q05']:.3f}, {m['weight']['q95']:.3f}], "
                       if weighed else f"mean log density {m['mean_log_density']:.1f}, ")
                    + ", ".join(f"{k} {t['mean']:.4g} [{t['q05']:.4g}, {t['q95']:.4g}]" for k, t in m["theta"].items())
                    for i, m in enumerate(summary["modes"]))]
    lines += ["", "## Figures", "", *(f"![{p.stem}]({p.name})" for p in plots), ""]
    return "\n".join(lines)


def _basis_fidelity_lines(fidelity: dict | None) -> list[str]:
    """A vector output's levels of fidelity, per basis component (docs/multifidelity.md), or nothing."""
    if not fidelity:
        return []
    columns = zip(fidelity["level_rho"], fidelity["loo_rmse"], fidelity["loo_rmse_without_low_fidelity"],
                  fidelity["top_level_variance_factor"], strict=True)
    rows = [f"| {c + 1} | {', '.join(f'{r:.3g}' for r in rho)} | {with_:.3g} | {without:.3g} | {factor:.3g} |"
            for c, (rho, with_, without, factor) in enumerate(columns)]
    return [(f"Emulator of {fidelity['levels']} fidelities, one per basis component (Kennedy & O'Hagan 2000): "
             "each level's scale on the one below, the leave-one-out error at the calibrated simulator's runs with "
             "and without the cheaper runs (standardised weights), and the factor on the top level's own "
             "variance."), "",
            "| component | rho | leave-one-out error, with | without | its variance times |", "|---|---|---|---|---|",
            *rows, ""]


def write_vector_calibration(result, folder: str | Path, warning_messages: list[str] | None = None,
                             units: dict[str, str] | None = None) -> dict:
    """summary.json, summary.csv, the curves per experiment, report.md and
    report.html of one vector-output calibration, in ``folder`` (made if
    missing); ``warning_messages`` and ``units`` as for :func:`write_calibration`."""
    from stancal.reporting.plots import plot_theta, plot_vector_curves

    folder = Path(folder)
    summary = result.to_summary_json()
    summary["warnings"] = _recorded(result) if warning_messages is None else list(warning_messages)
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "summary.json").write_text(json.dumps(summary, indent=2))
    table = result.summary()
    table.to_csv(folder / "summary.csv")
    plot_vector_curves(result, folder / "curves.png", units)
    plot_theta(result, folder / "theta.png", units)
    basis = summary["basis"]
    lines = [
        f"# Calibration report ({summary['method']}, {summary['backend']})", "",
        *([(f"Output basis: {basis['description']}; truncation error sd {basis['truncation_sd']:.3g}, "
            f"interpolation error sd {basis['interpolation_sd']:.3g} at the {basis['values_off_grid']} of "
            f"{basis['values']} values off the runs' grid (output units; each independent, beside the noise)."), ""]
          if basis else ["The Stan simulator is evaluated at every measured value (no output basis).", ""]),
        *_basis_fidelity_lines((basis or {}).get("fidelity")),
        *_parameters_and_sampler(summary, table),
        "", "## Figures", "", "![curves per experiment](curves.png)", "![theta](theta.png)", ""]
    (folder / "report.md").write_text("\n".join(lines))
    write_html(folder / "report.md")
    return summary
