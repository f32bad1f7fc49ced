"""A vector output with runs of a cheaper simulator over seeds
(docs/multifidelity.md, "Vector outputs"): tests/test_vector_multifidelity's
problem (cooling curves; Newton's law cheap, the radiative loss expensive;
k = 0.05) with fresh Latin hypercubes and fresh noise per seed. For each
seed, k's 90 % interval by quadrature of modular_vector.stan's density
(test_vector_outputs.log_density_reference, which the tests check against
the program to 1e-8) with the cheap runs, with the expensive runs alone,
and from the exact expensive simulator; and each emulator's RMS error and
90 % band at 300 fresh expensive curves.

    python benchmarks/vector_fidelity.py --seeds 10 --high 12 --out benchmarks/vector_fidelity_12.json
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

import test_vector_multifidelity as vm  # noqa: E402
from test_vector_outputs import log_density_reference  # noqa: E402

from stancal.fitting.stage_one import fit_vector_emulator, fit_vector_fidelity_emulator  # noqa: E402
from stancal.fitting.vector_calibrate import prediction_rows  # noqa: E402
from stancal.problem.options import VectorOptions  # noqa: E402
from stancal.problem.vector_data import VectorCalibrationData  # noqa: E402
from stancal.stan.vector_standata import modular_vector_data  # noqa: E402

UNIT_GRID = np.linspace(0.0005, 0.9995, 1600)  # k's unit box: steps of 5e-5 per minute
FRESH = 300  # fresh expensive curves for the emulators' errors


def interval(log_density: np.ndarray) -> list[float]:
    """k's 5 % and 95 % quantiles from a log density on UNIT_GRID."""
    weight = np.exp(log_density - log_density.max())
    cumulative = np.cumsum(weight / weight.sum())
    k = vm.K_BOUNDS[0] + np.ptp(vm.K_BOUNDS) * UNIT_GRID
    return [float(k[np.searchsorted(cumulative, 0.05)]), float(k[np.searchsorted(cumulative, 0.95)])]


def exact_interval(data: VectorCalibrationData) -> list[float]:
    """The same from the exact expensive simulator (known noise, uniform prior)."""
    physical = data.physical
    t, T0, y = (physical[c].to_numpy() for c in ("t", "T0", "temperature"))
    k = vm.K_BOUNDS[0] + np.ptp(vm.K_BOUNDS) * UNIT_GRID
    return interval(np.array([-0.5 * np.sum((y - vm.COOLING.with_loss(t, T0, kk)) ** 2) / vm.NOISE_SD**2
                              for kk in k]))


def measured(data: VectorCalibrationData, emulator, fresh, truth) -> dict:
    """k's interval by quadrature of the modular density, and the emulator at the fresh curves."""
    stan_data = modular_vector_data(data, VectorOptions("none", "known"), emulator, prediction_rows(data))
    low, high = interval(np.array([log_density_reference(stan_data, emulator, np.array([u])) for u in UNIT_GRID]))
    mean, variance = emulator.predict(data.scaling.to_unit(fresh, ["T0", "k"]), vm.GRID)
    return {"interval": [low, high], "width": high - low, "covers": bool(low <= vm.K_TRUE <= high),
            "rms": float(np.sqrt(np.mean((truth - mean) ** 2))),
            "inside_band": float(np.mean(np.abs(truth - mean) < 1.645 * np.sqrt(variance)))}


def one_seed(seed: int, high: int) -> dict:
    data = vm.problem(high=high, seed=seed)
    alone = VectorCalibrationData(data.source, "exp", ["T0"], "temperature", "t", {"k": vm.K_BOUNDS},
                                  runs=data.runs, run="run", noise_sd="sd")
    fresh = vm.settings(FRESH, 1000 + seed)
    truth = np.vstack([vm.COOLING.with_loss(vm.GRID, row.T0, row.k) for row in fresh.itertuples()])
    started = time.perf_counter()
    both = measured(data, fit_vector_fidelity_emulator(data, seed), fresh, truth)
    return {"seed": seed, "both": both, "alone": measured(alone, fit_vector_emulator(alone, seed), fresh, truth),
            "exact": exact_interval(data), "seconds": time.perf_counter() - started}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--high", type=int, default=12, help="expensive runs per seed (100 cheap)")
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args()
    rows = []
    for seed in range(args.seeds):
        rows.append(one_seed(seed, args.high))
        r = rows[-1]
        print(f"seed {seed}: with cheap runs {np.round(r['both']['interval'], 5)} rms {r['both']['rms']:.3f} "
              f"band {r['both']['inside_band']:.0%}; alone {np.round(r['alone']['interval'], 5)} rms "
              f"{r['alone']['rms']:.3f} band {r['alone']['inside_band']:.0%}; exact {np.round(r['exact'], 5)}; "
              f"{r['seconds']:.0f} s", flush=True)
    ratio = [r["both"]["width"] / r["alone"]["width"] for r in rows]
    error = [r["both"]["rms"] / r["alone"]["rms"] for r in rows]
    summary = {"high": args.high, "seeds": args.seeds,
               "covers_both": sum(r["both"]["covers"] for r in rows),
               "covers_alone": sum(r["alone"]["covers"] for r in rows),
               "width_ratio_median": float(np.median(ratio)), "width_ratio_range": [min(ratio), max(ratio)],
               "rms_ratio_median": float(np.median(error)), "rms_ratio_range": [min(error), max(error)],
               "rows": rows}
    print({k: v for k, v in summary.items() if k != "rows"})
    if args.out:
        args.out.write_text(json.dumps(summary, indent=1))


if __name__ == "__main__":
    main()
