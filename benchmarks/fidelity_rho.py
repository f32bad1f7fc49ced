"""A constant scale between fidelities against one linear in the inputs,
rho(x) = beta_0 + x' beta_x (Le Gratiet & Garnier 2014; Kennedy & O'Hagan
2000), on two-level cooling problems (docs/multifidelity.md):

- ``--case drifting``: the expensive simulator is Newton's law with a loss
  whose share grows linearly in time, T - Ta = (1 - DRIFT t) (T0 - Ta) e^(-k t):
  exactly rho(t) = 1 - DRIFT t times the cheap simulator's excess (1 to 0.64
  over the hour), the ambient part left to g_2;
- ``--case cooling_fidelity``: the case study's two simulators (Newton's
  law and the radiative loss), whose relation is not a scale at all.

Each seed draws fresh Latin hypercubes (150 cheap, 15 expensive runs; seed 0
of cooling_fidelity: the shipped ones) and fresh noise on the case study's
28 readings (k = 0.05). For each form of rho: stage 1's emulator at 500
fresh expensive runs (RMS error, share inside its 90 % band), and with
``--fit`` modular's 90 % interval of k (2 x (300 + 500)).

    python benchmarks/fidelity_rho.py [--case drifting] [--seeds 5] [--fit]
    python benchmarks/fidelity_rho.py --figure docs/img/multifidelity_rho.png

Writes benchmarks/fidelity_rho_CASE.json and prints one row per seed and form;
``--figure``: stage 1's linear rho along t on the drifting case (seed 0) against the truth.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

from conftest import case_study_module, fit  # noqa: E402

import stancal  # noqa: E402
from stancal.fitting.stage_one import fidelity_levels, fit_fidelity_emulator  # noqa: E402
from stancal.numerics import multifidelity as mf  # noqa: E402
from stancal.problem.config import load_config  # noqa: E402

CASE = ROOT / "case_studies" / "cooling_fidelity"
DRIFT = 0.006  # 1/min: the expensive simulator's extra loss share per minute
FORMS = ("constant", "linear")


def drifting(case):
    """The drifting expensive simulator: rho(t) = 1 - DRIFT t times Newton's excess."""
    return lambda t, T0, k: case.AMBIENT + (1 - DRIFT * t) * (case.newton(t, T0, k) - case.AMBIENT)


def problem(case_name: str, seed: int, form: str) -> tuple[stancal.CalibrationData, object]:
    """The readings with fresh noise, fresh runs, and the expensive simulator."""
    case = case_study_module(CASE)
    expensive = case.with_loss if case_name == "cooling_fidelity" else drifting(case)
    shipped = load_config(CASE / "config.toml").data
    physical = shipped.source.copy()
    rng = np.random.default_rng(seed)
    physical["temperature"] = (expensive(physical["t"], physical["T0"], case.K_TRUE)
                               + rng.normal(0, case.NOISE_SD, len(physical)))
    runs = (shipped.runs_by_fidelity() if seed == 0 and case_name == "cooling_fidelity"
            else [case.runs(case.newton, 150, 10 * seed + 1), case.runs(expensive, 15, 10 * seed + 2)])
    data = stancal.CalibrationData(physical, shipped.inputs, shipped.output, {"k": case.K_BOUNDS}, runs=runs,
                                   low_fidelity_rho=form)
    return data, expensive


def holdout(data: stancal.CalibrationData, levels: list[mf.Level], expensive, case) -> dict:
    """RMS error (deg C) of the emulator's mean at 500 fresh expensive runs and the share inside its 90 % band."""
    fresh = case.design(500, seed=99)
    truth = expensive(fresh["t"], fresh["T0"], fresh["k"]).to_numpy()
    unit = np.hstack([data.scaling.to_unit(fresh, data.inputs), data.scaling.to_unit(fresh, data.theta_names)])
    mean, variance = mf.predict(levels, unit)
    error = data.scaling.original(mean) - truth
    inside = np.abs(error) <= 1.645 * np.sqrt(variance) * data.scaling.y_scale
    return {"rmse_degC": float(np.sqrt(np.mean(error**2))), "within_90_band": float(inside.mean())}


def one(case_name: str, seed: int, form: str, sample: bool) -> dict:
    started = time.perf_counter()
    case = case_study_module(CASE)
    data, expensive = problem(case_name, seed, form)
    row = {"seed": seed, "rho": form}
    if sample:
        result = fit(data, method="modular", discrepancy="none", chains=2, warmup=300, draws=500, seed=seed + 1)
        emulator = result.emulator
        k = result.theta_summary()["k"]
        row |= {"q05": k["q05"], "q95": k["q95"], "width_90": k["q95"] - k["q05"],
                "covered": bool(k["q05"] <= case.K_TRUE <= k["q95"]),
                "max_rhat": float(result.diagnostics.max_rhat), "divergences": int(result.diagnostics.divergences)}
    else:
        emulator = fit_fidelity_emulator(data, seed)
    levels = fidelity_levels(data, emulator["hyperparameters"]["levels"])
    row |= holdout(data, levels, expensive, case) | {
        "level_rho": emulator["level_rho"], "level_rho_range": emulator.get("level_rho_range"),
        "level_rho_slope": emulator.get("level_rho_slope"),
        "loo_rmse": emulator["loo_rmse"], "top_level_variance_factor": emulator["top_level_variance_factor"],
        "seconds": time.perf_counter() - started}
    return row


def figure(path: Path) -> None:
    """Stage 1's rho(t) (T0 at its centre) on the drifting case, seed 0, against the truth 1 - DRIFT t."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    data, _ = problem("drifting", 0, "linear")
    emulator = fit_fidelity_emulator(data, 0)
    profile = emulator["level_rho_profile"][0]
    t = np.asarray(profile["inputs"]["t"])
    fig, ax = plt.subplots(figsize=(5, 3))
    ax.plot(t, profile["rho"]["t"], "o-", label="stage 1's linear rho (150 + 15 runs)")
    ax.plot(t, 1 - DRIFT * t, "k--", lw=1, label="truth: 1 - 0.006 t")
    constant = fit_fidelity_emulator(problem("drifting", 0, "constant")[0], 0)["level_rho"][0]
    ax.axhline(constant, color="C1", lw=1, label=f"constant rho: {constant:.3g}")
    ax.set_xlabel("t (min), T0 at its centre")
    ax.set_ylabel("rho: expensive on cheap (-)")
    ax.legend(fontsize=8)
    ax.set_title("The scale between the fidelities along t", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=150)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--case", default="drifting", choices=["drifting", "cooling_fidelity"])
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--fit", action="store_true", help="also calibrate (modular, 2 x (300 + 500))")
    parser.add_argument("--figure", type=Path, help="only draw stage 1's rho(t) on the drifting case to this PNG")
    args = parser.parse_args()
    if args.figure:
        figure(args.figure)
        return
    rows = []
    for seed in range(args.seeds):
        for form in FORMS:
            rows.append(one(args.case, seed, form, args.fit))
            r = rows[-1]
            interval = (f"[{r['q05']:.4f}, {r['q95']:.4f}] width {r['width_90']:.4f} "
                        f"{'covers' if r['covered'] else 'misses'} R-hat {r['max_rhat']:.3f}" if args.fit else "")
            print(f"| {seed} | {form} | {r['rmse_degC']:.3f} | {r['within_90_band']:.2f} | {r['level_rho_range']} "
                  f"| {interval} | {r['seconds']:.0f} s |", flush=True)
            (Path(__file__).parent / f"fidelity_rho_{args.case}.json").write_text(json.dumps(rows, indent=2))


if __name__ == "__main__":
    main()
