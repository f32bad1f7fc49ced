"""Designed runs against as many Latin-hypercube runs, on the pin fin of
case_studies/design_loop (docs/design.md): for each seed, new measurement
noise and a new initial Latin hypercube of 40 runs; the design loop
(stancal.run_waves, 20 runs a wave until NROY stops shrinking, at most
WAVES waves) against a Latin hypercube of the same count over the whole box.
For each: the emulator's error at the true theta (its mean at the measured
inputs against the simulator there, RMS, and its predictive sd), then a
``modular`` calibration on the runs (2 chains) and theta's 90 % interval
widths, as a share of the prior's, and whether the truth lies inside. Per
seed and wave it also records whether NROY still holds the truth: the true
theta's implausibility under every wave's cut so far, against the cutoff
(history matching must never rule the truth out; Vernon et al. 2010).

    python benchmarks/design_vs_lhs.py [--seeds 4 | --seed-list 3 4] [--chains 2 --warmup 500 --draws 500]
                                       [--waves-only]

``--waves-only`` runs the design loop and the truth's check alone, no fits.

Writes benchmarks/design_vs_lhs.json and docs/img/design_vs_lhs.png and prints a table.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
CASE = ROOT / "case_studies" / "design_loop"
sys.path[:0] = [str(ROOT), str(CASE)]

from make_data import INITIAL_RUNS, initial_runs, physical  # noqa: E402
from simulator import THETA, TRUTH, fin_temperature  # noqa: E402

import stancal  # noqa: E402
from stancal.designing.targets import DesignSettings, UnitBox, run_table  # noqa: E402
from stancal.designing.waves import fit_emulator  # noqa: E402
from stancal.problem.config import load_config  # noqa: E402

WAVES, RUNS_PER_WAVE, STOP_SHRINK = 6, 20, 0.9
CONFIG = load_config(CASE / "config.toml")  # the case study's problem: its inputs, theta bounds and [design]
SETTINGS = DesignSettings(**CONFIG.design)
ACTIVE = ("h", "k", "T_a", "eta")


def data_with(table: pd.DataFrame, runs: pd.DataFrame) -> stancal.CalibrationData:
    """The case study's problem on other measurements and runs."""
    bounds = {p.name: (p.lower, p.upper) for p in CONFIG.data.parameters}
    return stancal.CalibrationData(table, CONFIG.data.inputs, CONFIG.data.output, bounds, runs=runs)


def emulator_error(data: stancal.CalibrationData, seed: int) -> dict:
    """The emulator of all the runs at the measured inputs and the true theta."""
    box = UnitBox.of(data)
    emulator = fit_emulator(data, *run_table(data, box), seed)
    truth = data.physical[box.inputs].assign(**TRUTH)
    mean, variance = emulator.at(box.inputs_to_unit(truth), box.theta_to_unit([[TRUTH[n] for n in box.nroy_names]]))
    error = mean[0] - fin_temperature(truth)
    return {"rms_error": float(np.sqrt(np.mean(error**2))), "mean_sd": float(np.sqrt(variance[0]).mean())}


def calibrated(data: stancal.CalibrationData, sampler: dict, seed: int) -> dict:
    started = time.perf_counter()
    result = stancal.calibrate(data, method="modular", seed=seed, **sampler)
    draws = result.theta_draws()
    out = {"fit_s": time.perf_counter() - started,
           "diagnostics": result.diagnostics.summary() if result.diagnostics else None}
    for name, (low, high) in THETA.items():
        q05, q95 = np.quantile(draws[name], [0.05, 0.95])
        out[name] = {"width_share": float((q95 - q05) / (high - low)), "covers": bool(q05 <= TRUTH[name] <= q95)}
    return out


def truth_by_wave(loop) -> list[dict]:
    """Each wave's NROY fraction and the true theta's implausibility under
    every cut up to that wave; the truth is in NROY when it is at most the cutoff."""
    rows = []
    for design in loop.designs:
        match = design.match
        value = float(match.implausibility(pd.DataFrame([TRUTH]))[0])
        rows.append({"wave": len(match.waves), "runs": match.waves[-1].runs_total,
                     "nroy_fraction": match.nroy_fraction, "truth_implausibility": value,
                     "truth_in_nroy": value <= match.cutoff})
    return rows


def one_seed(seed: int, sampler: dict | None) -> dict:
    table = physical(seed=1000 + seed)
    start = data_with(table, initial_runs(INITIAL_RUNS, seed=seed))
    loop = stancal.run_waves(start, simulator=fin_temperature, waves=WAVES, runs_per_wave=RUNS_PER_WAVE,
                             settings=SETTINGS, seed=seed, stop_shrink=STOP_SHRINK)
    designed = loop.data
    count = len(designed.runs)
    lhs = data_with(table, initial_runs(count, seed=500 + seed))
    row = {"seed": seed, "runs": count, "nroy_fraction_by_wave": loop.fractions, "truth_by_wave": truth_by_wave(loop)}
    for wave in row["truth_by_wave"]:
        print(f"seed {seed} wave {wave['wave']}: {wave['runs']} runs, NROY {wave['nroy_fraction']:.3g}, the truth's "
              f"implausibility {wave['truth_implausibility']:.2f}: "
              f"{'in NROY' if wave['truth_in_nroy'] else 'RULED OUT'}", flush=True)
    if sampler is None:
        return row
    for name, data in (("designed", designed), ("lhs", lhs)):
        row[name] = {**emulator_error(data, seed), **calibrated(data, sampler, seed)}
        print(f"seed {seed} {name}: {json.dumps(row[name])}", flush=True)
    return row


def plot(rows: list[dict], path: Path) -> None:
    """theta's 90 % interval width over its prior's, each seed a point, per arm; coverage in the labels."""
    from stancal.reporting.plots import finish, pyplot

    plt = pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(9, 3.8), layout="constrained", width_ratios=[3, 1])
    for shift, (arm, colour) in zip((-0.12, 0.12), (("designed", "tab:red"), ("lhs", "tab:blue")), strict=True):
        for q, name in enumerate(THETA):
            widths = [r[arm][name]["width_share"] for r in rows]
            covered = sum(r[arm][name]["covers"] for r in rows)
            axes[0].scatter(np.full(len(widths), q + shift), widths, color=colour, s=18,
                            label=("designed runs (waves)" if arm == "designed" else "Latin hypercube, same count")
                            if q == 0 else None)
            axes[0].annotate(f"{covered}/{len(rows)}", (q + shift, max(widths)), textcoords="offset points",
                             xytext=(0, 4), ha="center", fontsize=7, color=colour)
        errors = [r[arm]["rms_error"] for r in rows]
        axes[1].scatter(np.full(len(errors), 0.5 + 2 * shift), errors, color=colour, s=18)
    axes[0].set_xticks(range(len(THETA)), list(THETA))
    axes[0].set_ylabel("90 % interval width / prior width")
    axes[0].set_title("theta's 90 % intervals (label: seeds covering the truth)", fontsize=9)
    axes[0].legend(fontsize=7)
    axes[1].set_xticks([0.26, 0.74], ["designed", "LHS"])
    axes[1].set_xlim(0, 1)
    axes[1].set_yscale("log")
    axes[1].set_ylabel("emulator RMS error at the true theta [°C]")
    axes[1].set_title("emulator near the truth", fontsize=9)
    finish(fig, path)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=4)
    parser.add_argument("--seed-list", type=int, nargs="+", help="these seeds instead of 1 to --seeds")
    parser.add_argument("--chains", type=int, default=2)
    parser.add_argument("--warmup", type=int, default=500)
    parser.add_argument("--draws", type=int, default=500)
    parser.add_argument("--waves-only", action="store_true", help="the design loop and the truth's check, no fits")
    args = parser.parse_args()
    sampler = None if args.waves_only else {"chains": args.chains, "warmup": args.warmup, "draws": args.draws}
    name = "design_vs_lhs_waves.json" if sampler is None else "design_vs_lhs.json"
    rows = []
    for seed in args.seed_list or range(1, args.seeds + 1):
        rows.append(one_seed(seed, sampler))  # written after each seed: a long run keeps what it finished
        (Path(__file__).parent / name).write_text(json.dumps({"sampler": sampler, "rows": rows}, indent=1))
    print_truth_table(rows)
    if sampler is None:
        return
    plot(rows, ROOT / "docs" / "img" / "design_vs_lhs.png")
    print("| arm | runs | emulator RMS error at the truth | " + " | ".join(f"{n} width / prior, covered"
                                                                            for n in ACTIVE) + " |")
    for arm in ("designed", "lhs"):
        cells = [f"{np.mean([r[arm][n]['width_share'] for r in rows]):.3f}, "
                 f"{sum(r[arm][n]['covers'] for r in rows)}/{len(rows)}" for n in ACTIVE]
        print(f"| {arm} | {np.mean([r['runs'] for r in rows]):.0f} | "
              f"{np.mean([r[arm]['rms_error'] for r in rows]):.3g} °C | " + " | ".join(cells) + " |")


def print_truth_table(rows: list[dict]) -> None:
    """Per wave: the seeds that reached it, those whose NROY still holds the truth, the largest implausibility."""
    print("| wave | seeds | truth in NROY | largest implausibility of the truth |")
    print("|---|---|---|---|")
    for wave in range(1, max(len(r["truth_by_wave"]) for r in rows) + 1):
        at = [w for r in rows for w in r["truth_by_wave"] if w["wave"] == wave]
        print(f"| {wave} | {len(at)} | {sum(w['truth_in_nroy'] for w in at)} | "
              f"{max(w['truth_implausibility'] for w in at):.2f} |")


if __name__ == "__main__":
    main()
