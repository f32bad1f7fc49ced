"""Calibrate SEPIA's Al-5083 flyer plates with stancal and compare theta with
a reference posterior (SEPIA's, when its numbers are at hand): the time, the
ESS/s of theta, each parameter's posterior mean and sd against its prior sd,
and the per-shot features against the predictive bands (shots.png).

    .venv/bin/python case_studies/al5083/compare.py [--out out/al5083] [--chains 4]
        [--warmup 500] [--draws 500] [--seed 1] [--reference sepia_posterior.csv]
        [--config config_subset.toml]

``--reference``: a CSV with columns name, mean, sd (theta in the config's
units): the posterior to compare with; by default sepia_posterior.csv with
config.toml and none with another config (for the 100-run subset,
benchmarks/al5083_sepia.py compares with SEPIA's recorded runs). SEPIA's example (Al_5083_calibration.py:
11 principal components, no discrepancy, 10,000 MCMC iterations) writes its
samples to a pickle that is not in SEPIA's repository, and no version of its
notebook there stores the posterior's output (docs/al5083.md says what was
searched); run that example and summarise its theta to make this file. The
method is Higdon et al. (2008, JASA 103) with the modular stage 2 of Liu,
Bayarri & Berger (2009, Bayesian Analysis 4).
"""

from __future__ import annotations

import argparse
import json
import logging
import time
from pathlib import Path

import numpy as np
import pandas as pd

import stancal
from stancal.fitting.vector_calibrate import calibrate_vector
from stancal.problem.config import load_config
from stancal.reporting.plots import pyplot

HERE = Path(__file__).resolve().parent


def arguments() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("out/al5083"))
    parser.add_argument("--chains", type=int, default=4)
    parser.add_argument("--warmup", type=int, default=500)
    parser.add_argument("--draws", type=int, default=500)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--reference", type=Path, default=None,
                        help="default: sepia_posterior.csv with config.toml (all 1,000 runs); none with any other "
                             "config, whose runs that file was not made from")
    parser.add_argument("--config", type=Path, default=HERE / "config.toml",
                        help="config_subset.toml: the 100 runs SEPIA was run on (benchmarks/al5083_sepia.py)")
    args = parser.parse_args()
    if args.reference is None and args.config.resolve() == (HERE / "config.toml").resolve():
        args.reference = HERE / "sepia_posterior.csv"
    return args


def theta_table(result, reference: pd.DataFrame | None) -> pd.DataFrame:
    """Per parameter: prior sd (uniform), stancal's mean, sd and 90 % interval,
    sd / prior sd, and the reference's mean and sd with the gap in its sds."""
    summary = result.theta_summary()
    rows = []
    for p in result.data.parameters:
        s, prior_sd = summary[p.name], (p.upper - p.lower) / np.sqrt(12)
        row = {"name": p.name, "prior_sd": prior_sd, "mean": s["mean"], "sd": s["sd"], "q05": s["q05"],
               "q95": s["q95"], "sd_over_prior_sd": s["sd"] / prior_sd, "ess_bulk": s["ess_bulk"], "rhat": s["rhat"]}
        if reference is not None and p.name in reference.index:
            ref = reference.loc[p.name]
            row |= {"reference_mean": ref["mean"], "reference_sd": ref["sd"],
                    "gap_in_reference_sds": (s["mean"] - ref["mean"]) / ref["sd"], "sd_ratio": s["sd"] / ref["sd"]}
        rows.append(row)
    return pd.DataFrame(rows).set_index("name")


def plot_shots(result, path: Path) -> None:
    """Per shot: its four features, measured (with the known sd's 90 %
    interval) against zeta's 90 % band; below, zeta minus the measurement."""
    plt = pyplot()
    data, predictions = result.data, result.idata["predictions"]
    features = np.asarray(predictions[data.output_index[0]])
    zeta = np.asarray(predictions["zeta"]).reshape(-1, *predictions["zeta"].shape[2:])
    names = list(data.experiments.index)
    fig, axes = plt.subplots(2, len(names), figsize=(3.8 * len(names), 5.6), layout="constrained", sharex="col")
    for e, name in enumerate(names):
        measured = data.physical[data.physical[data.experiment] == name]
        at = np.searchsorted(features, measured[data.output_index[0]].to_numpy())
        draws = zeta[:, e, at]
        y, sd = measured[data.output].to_numpy(), measured[data.noise_sd].to_numpy()
        labels = data.source.loc[measured.index, "column"].tolist()
        x = np.arange(len(y))
        for row, (values, centre) in enumerate(((draws, 0.0), (draws - y, y))):
            ax = axes[row, e]
            low, mid, high = np.quantile(values, [0.05, 0.5, 0.95], axis=0)
            ax.bar(x, high - low, bottom=low, width=0.5, color="C0", alpha=0.35, label="ζ, 90 % band")
            ax.scatter(x, mid, marker="_", s=200, color="C0", label="ζ, median")
            shown = y - centre
            ax.errorbar(x, shown, yerr=1.645 * sd, fmt="o", color="k", ms=3, capsize=3,
                        label="measured ± 1.645 sd (known noise)")
            ax.set_xticks(x, labels)
        axes[0, e].set_title(f"shot {name}", fontsize=10)
        axes[1, e].axhline(0, color="grey", lw=0.8)
    axes[0, 0].set_ylabel("free-surface velocity feature (m/s)")
    axes[1, 0].set_ylabel("ζ − measured (m/s)")
    axes[0, 0].legend(fontsize=7)
    fig.suptitle(f"Al-5083 flyer plates: features against the predictive bands ({result.method})")
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main() -> None:
    args = arguments()
    logging.basicConfig(format="%(name)s: %(message)s")
    logging.getLogger("stancal").setLevel(logging.INFO)  # stage 1 and sampling progress, as the CLI shows them
    args.out.mkdir(parents=True, exist_ok=True)
    problem = load_config(args.config)
    started = time.perf_counter()
    result = calibrate_vector(problem.data, chains=args.chains, warmup=args.warmup, draws=args.draws, seed=args.seed,
                              out_dir=args.out, **problem.model)
    wall = time.perf_counter() - started
    reference = (pd.read_csv(args.reference).set_index("name")
                 if args.reference is not None and args.reference.is_file() else None)
    table = theta_table(result, reference)
    sample_s = result.timing["sample_s"]
    summary = {
        "method": result.method, "chains": args.chains, "warmup": args.warmup, "draws": args.draws,
        "wall_s": wall, "sample_s": sample_s, "max_rhat": result.diagnostics.max_rhat,
        "divergences": result.diagnostics.divergences,
        "theta_ess_bulk_min": float(table["ess_bulk"].min()),
        "theta_ess_bulk_median": float(table["ess_bulk"].median()),
        "theta_min_ess_per_s_sampling": float(table["ess_bulk"].min() / sample_s),
        "theta_min_ess_per_s_wall": float(table["ess_bulk"].min() / wall),
        "reference": str(args.reference) if reference is not None else None,
        "theta": json.loads(table.to_json(orient="index")),
    }
    (args.out / "compare.json").write_text(json.dumps(summary, indent=2))
    table.to_csv(args.out / "theta_compare.csv")
    stancal.write_calibration(result, args.out, units=problem.units)  # report.md, curves.png, theta.png
    plot_shots(result, args.out / "shots.png")
    with pd.option_context("display.width", 200, "display.float_format", "{:.4g}".format):
        print(table)
    print(f"{result.method}: {wall:.0f} s in all, {sample_s:.0f} s sampling; R-hat {summary['max_rhat']:.3f}, "
          f"{summary['divergences']} divergences; theta's min bulk ESS {summary['theta_ess_bulk_min']:.0f} "
          f"({summary['theta_min_ess_per_s_sampling']:.2f} ESS/s of sampling, "
          f"{summary['theta_min_ess_per_s_wall']:.2f} of the whole run)")
    if reference is None:
        print(f"no reference posterior{f' at {args.reference}' if args.reference else ''}: stancal's numbers only")


if __name__ == "__main__":
    main()
