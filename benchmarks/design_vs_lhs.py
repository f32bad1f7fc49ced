"""Designed runs against as many Latin-hypercube runs, on the pin fin of
case_studies/design_loop (docs/design.md): for each seed, new measurement
noise and a new initial Latin hypercube of 40 runs; the design loop
(stancal.run_waves, 20 runs a wave until NROY stops shrinking, at most
WAVES waves) against a Latin hypercube of the same count over the whole box.
For each: the emulator's error at the true theta (its mean at the measured
inputs against the simulator there, RMS, and its predictive sd), then a
``modular`` calibration on the runs (2 chains) and theta's 90 % interval
widths, as a share of the prior's, and whether the truth lies inside;
beside it, theta's posterior with the simulator itself in place of the
emulator (cheap here), the discrepancy and noise at the fit's medians
(exact_posterior), and the modular likelihood along the h / k ridge, which
the simulator leaves flat (ridge_profile): what picks h on it. Per
seed and wave it also records whether NROY still holds the truth: the true
theta's implausibility under every wave's cut so far, against the cutoff
(history matching must never rule the truth out; Vernon et al. 2010).

    python benchmarks/design_vs_lhs.py [--seeds 4 | --seed-list 3 4] [--chains 2 --warmup 500 --draws 1000]
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


def calibrated(data: stancal.CalibrationData, sampler: dict, seed: int) -> tuple[object, dict]:
    """A modular calibration on the runs, and theta's 90 % intervals."""
    started = time.perf_counter()
    result = stancal.calibrate(data, method="modular", seed=seed, **sampler)
    draws = result.theta_draws()
    out = {"fit_s": time.perf_counter() - started,
           "diagnostics": result.diagnostics.summary() if result.diagnostics else None}
    for name, (low, high) in THETA.items():
        q05, q95 = np.quantile(draws[name], [0.05, 0.95])
        out[name] = {"width_share": float((q95 - q05) / (high - low)), "covers": bool(q05 <= TRUTH[name] <= q95),
                     "interval": [float(q05), float(np.median(draws[name])), float(q95)]}
    return result, out


def fit_medians(result) -> dict:
    """The calibration's discrepancy and noise at their posterior medians, original units."""
    posterior = result.idata["posterior"]
    return {"delta_sd": float(posterior["delta_sd"].median()), "noise_sd": float(posterior["noise_sd"].median()),
            "delta_length_scale": posterior["delta_length_scale"].median(dim=("chain", "draw")).values.tolist()}


def exact_posterior(table: pd.DataFrame, hyper: dict, seed: int, draws: int = 200_000) -> dict:
    """theta's posterior with the simulator itself in place of the emulator
    (it is cheap here), the discrepancy GP and the noise held at a
    calibration's posterior medians (``hyper``): what the data say about
    theta with no emulator error. Two-stage importance sampling (Oh & Berger
    1992, "Adaptive importance sampling in Monte Carlo integration", J.
    Stat. Comput. Simul. 41): a uniform sample of the active theta's box,
    then a normal fitted to its weighted draws, its covariance doubled. c_p has no
    effect on the simulator: its posterior is its prior."""
    from scipy import linalg, stats

    from stancal.numerics.kernels import ard_cross_cov

    rng = np.random.default_rng(seed)
    low, width = (np.array([THETA[n][0] for n in ACTIVE]), np.array([np.ptp(THETA[n]) for n in ACTIVE]))
    x, y = table[CONFIG.data.inputs].to_numpy(float), table[CONFIG.data.output].to_numpy(float)
    covariance = ard_cross_cov(x, x, 1, hyper["delta_sd"], np.array(hyper["delta_length_scale"]))
    factor = linalg.cho_factor(covariance + hyper["noise_sd"] ** 2 * np.eye(len(y)), lower=True)

    def log_likelihood(unit: np.ndarray) -> np.ndarray:
        theta = low + unit * width
        points = pd.DataFrame({**{c: np.tile(x[:, j], len(unit)) for j, c in enumerate(CONFIG.data.inputs)},
                               **{n: np.repeat(theta[:, q], len(y)) for q, n in enumerate(ACTIVE)}})
        residual = y - fin_temperature(points).reshape(len(unit), len(y))
        return -0.5 * np.sum(residual.T * linalg.cho_solve(factor, residual.T), axis=0)

    unit = rng.uniform(size=(draws, len(ACTIVE)))
    weights = normalised(log_likelihood(unit))
    mean = weights @ unit
    spread = 2 * np.cov(unit.T, aweights=weights)
    unit = rng.multivariate_normal(mean, spread, size=draws)
    unit = unit[np.all((unit > 0) & (unit < 1), axis=1)]  # the prior's box; truncation is a constant in the weights
    weights = normalised(log_likelihood(unit) - stats.multivariate_normal(mean, spread).logpdf(unit))
    out = {"ess": float(1 / np.sum(weights**2))}
    for q, name in enumerate(ACTIVE):
        values = low[q] + unit[:, q] * width[q]
        order = np.argsort(values)
        q05, q50, q95 = values[order][np.searchsorted(np.cumsum(weights[order]), [0.05, 0.5, 0.95])]
        sd = np.sqrt(weights @ (values - weights @ values) ** 2)
        out[name] = {"width_share": float((q95 - q05) / width[q]), "covers": bool(q05 <= TRUTH[name] <= q95),
                     "interval": [float(q05), float(q50), float(q95)],
                     "sd_share": float(sd / (width[q] / np.sqrt(12)))}  # posterior sd over the uniform prior's
    return out


RIDGE_POINTS = 9


def ridge_profile(data: stancal.CalibrationData, result, hyper: dict, exact: dict) -> dict:
    """The modular likelihood along the ridge the data cannot cut, h / k at
    the exact posterior's median (T_a, eta at theirs, c_p mid-range): log
    N(y; m(theta), V(theta) + K_delta + noise) with the calibration's stage-1
    emulator (mean m, covariance V) and its discrepancy and noise at their
    medians, and its log-determinant part; and the same with the simulator
    itself (V = 0), which is flat there. h from 1.05 times the lowest the
    box allows on the ridge to 0.95 times the highest."""
    from scipy import linalg

    from stancal.designing.emulators import calibration_emulator, pairs
    from stancal.numerics.kernels import ard_cross_cov

    box = UnitBox.of(data)
    emulator = calibration_emulator(data, box, result.emulator)
    x, y = data.physical[data.inputs], data.physical[data.output].to_numpy(float)
    fixed = ard_cross_cov(x.to_numpy(float), x.to_numpy(float), 1, hyper["delta_sd"],
                          np.array(hyper["delta_length_scale"])) + hyper["noise_sd"] ** 2 * np.eye(len(y))
    ratio = exact["h"]["interval"][1] / exact["k"]["interval"][1]
    lowest, highest = max(THETA["h"][0], ratio * THETA["k"][0]), min(THETA["h"][1], ratio * THETA["k"][1])
    rows = {"h": [], "emulator": [], "log_determinant": [], "exact": []}
    for h in np.linspace(1.05 * lowest, 0.95 * highest, RIDGE_POINTS):
        theta = {"h": h, "k": h / ratio, "T_a": exact["T_a"]["interval"][1], "eta": exact["eta"]["interval"][1],
                 "c_p": float(np.mean(THETA["c_p"]))}
        points = pairs(box.inputs_to_unit(x), box.theta_to_unit([[theta[n] for n in box.nroy_names]]))
        mean = emulator.center + emulator.scale * emulator.gp.predict(points)[0]
        covariance = fixed + emulator.scale**2 * emulator.gp.covariance(points, points)
        factor = linalg.cholesky(covariance, lower=True)
        log_determinant = -float(np.sum(np.log(np.diag(factor))))
        residual = linalg.solve_triangular(factor, y - mean, lower=True)
        exact_residual = y - fin_temperature(x.assign(**theta))
        rows["h"].append(float(h))
        rows["emulator"].append(log_determinant - 0.5 * float(residual @ residual))
        rows["log_determinant"].append(log_determinant)
        rows["exact"].append(-0.5 * float(exact_residual @ linalg.solve(fixed, exact_residual)))
    return rows


def normalised(log_weights: np.ndarray) -> np.ndarray:
    weights = np.exp(log_weights - log_weights.max())
    return weights / weights.sum()


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
        result, fitted = calibrated(data, sampler, seed)
        hyper = fit_medians(result)
        exact = exact_posterior(table, hyper, seed)
        row[name] = {**emulator_error(data, seed), **fitted, "hyper": hyper, "exact": exact,
                     "ridge": ridge_profile(data, result, hyper, exact)}
        print(f"seed {seed} {name}: {json.dumps(row[name])}", flush=True)
    return row


ARMS = (("designed", "tab:red", "designed runs (waves)"), ("lhs", "tab:blue", "Latin hypercube, same count"))


def plot(rows: list[dict], path: Path) -> None:
    """Per theta, each seed's 90 % interval (bar) and median (dot) from each
    arm and from the simulator itself (at the designed fit's discrepancy),
    the truth as a line, in theta's units on its prior range; and the
    emulator's RMS error at the true theta with its own predictive sd."""
    from stancal.reporting.plots import finish, pyplot

    plt = pyplot()
    fig, axes = plt.subplots(2, 3, figsize=(11, 6.4), layout="constrained")
    seeds = [r["seed"] for r in rows]
    for ax, name in zip(axes.flat, THETA, strict=False):
        series = [[r[arm][name]["interval"] for r in rows] for arm, _, _ in ARMS]
        styles = [(colour, label) for _, colour, label in ARMS]
        if name in ACTIVE:  # c_p does not enter the simulator: its exact posterior is its prior
            series.append([r["designed"]["exact"][name]["interval"] for r in rows])
            styles.append(("grey", "the simulator itself (no emulator)"))
        for shift, intervals, (colour, label) in zip((-0.22, 0.0, 0.22), series, styles, strict=False):
            low, mid, high = np.array(intervals).T
            ax.vlines(np.arange(len(rows)) + shift, low, high, color=colour, lw=2.5, label=f"{label}: 90 % interval")
            ax.plot(np.arange(len(rows)) + shift, mid, "o", color=colour, ms=3.5)
        ax.axhline(TRUTH[name], color="black", ls="--", lw=1, label="truth")
        covered = ", ".join(f"{sum(r[arm][name]['covers'] for r in rows)}/{len(rows)} {short}"
                            for (arm, _, _), short in zip(ARMS, ("designed", "LHS"), strict=True))
        ax.set_title(f"{name}: truth covered {covered}", fontsize=9)
        ax.set_ylim(*THETA[name])
        ax.set_xlim(-0.5, len(rows) - 0.5)
        ax.set_xticks(range(len(rows)), [str(s) for s in seeds])
        ax.set_xlabel("seed")
        ax.set_ylabel(f"{name} [{CONFIG.units.get(name, '–')}]")
    fig.legend(*axes[0, 0].get_legend_handles_labels(), loc="outside lower center", ncol=4, fontsize=8)
    ax = axes.flat[len(THETA)]
    for shift, (arm, colour, label) in zip((-0.15, 0.15), ARMS, strict=True):
        ax.plot(np.arange(len(rows)) + shift, [r[arm]["rms_error"] for r in rows], "o", color=colour,
                label=f"{label}: RMS error")
        ax.plot(np.arange(len(rows)) + shift, [r[arm]["mean_sd"] for r in rows], "x", color=colour,
                label=f"{label}: its predictive sd")
    ax.set_yscale("log")
    ax.set_xlim(-0.5, len(rows) - 0.5)
    ax.set_xticks(range(len(rows)), [str(s) for s in seeds])
    ax.set_xlabel("seed (runs: " + ", ".join(str(r["runs"]) for r in rows) + ")")
    ax.set_ylabel("emulator at the true theta [°C]")
    ax.set_title("the emulator of all the runs near the truth", fontsize=9)
    largest = max(max(r[arm]["rms_error"], r[arm]["mean_sd"]) for r in rows for arm, _, _ in ARMS)
    ax.set_ylim(top=4 * largest)  # room for the legend above the points
    ax.legend(fontsize=7, loc="upper center")
    finish(fig, path)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=4)
    parser.add_argument("--seed-list", type=int, nargs="+", help="these seeds instead of 1 to --seeds")
    parser.add_argument("--chains", type=int, default=2)
    parser.add_argument("--warmup", type=int, default=500)
    parser.add_argument("--draws", type=int, default=1000)  # the docs' table
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
    print_summary(rows)


def print_summary(rows: list[dict]) -> None:
    """Per arm: theta's interval widths over the prior's (mean over seeds)
    and the seeds covering the truth, the emulator's error at the truth,
    the fits' health; then the exact simulator's intervals at each arm's
    discrepancy, and the likelihood's range along the h / k ridge."""
    print("| runs | emulator RMS error at the true theta (its sd) | "
          + " | ".join(THETA) + " | fits with divergences |\n|---|---|" + "---|" * (len(THETA) + 1))
    for arm, _, label in ARMS:
        cells = [f"{np.mean([r[arm][n]['width_share'] for r in rows]):.2f} "
                 f"({sum(r[arm][n]['covers'] for r in rows)}/{len(rows)})" for n in THETA]
        divergent = [d for r in rows if (d := (r[arm]["diagnostics"] or {}).get("divergences"))]
        print(f"| {label} | {np.mean([r[arm]['rms_error'] for r in rows]):.2f} °C "
              f"({np.mean([r[arm]['mean_sd'] for r in rows]):.2f}) | " + " | ".join(cells)
              + f" | {len(divergent)} of {len(rows)} {divergent or ''} |")
    for arm, _, label in ARMS:
        cells = [f"{np.mean([r[arm]['exact'][n]['width_share'] for r in rows]):.2f} "
                 f"({sum(r[arm]['exact'][n]['covers'] for r in rows)}/{len(rows)})" for n in ACTIVE]
        print(f"| the simulator itself, at the {label} fit's discrepancy | – | " + " | ".join(cells) + " | | |")
    print("\nthe log likelihood's range along the h / k ridge (h at its peak): emulator, its log-determinant, exact")
    for arm, _, label in ARMS:
        for r in rows:
            ridge = r[arm]["ridge"]
            peak = ridge["h"][int(np.argmax(ridge["emulator"]))]
            print(f"seed {r['seed']} {label}: {np.ptp(ridge['emulator']):.1f} (peak at h = {peak:.1f}), "
                  f"{np.ptp(ridge['log_determinant']):.1f}, {np.ptp(ridge['exact']):.3f}; h's exact posterior sd / "
                  f"prior sd {r[arm]['exact']['h']['sd_share']:.2f}")


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
