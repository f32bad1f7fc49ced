"""Simulation-based calibration of stancal's program families, one table
row each: S simulations, L draws per fit, each parameter's p-value, wall
time (one process; issue 16 puts these on Dask).

    python benchmarks/sbc_families.py [--family koh koh_none] [--sims 200]

Writes benchmarks/sbc.json (merged with earlier rows) and prints the table.
Families so far, all on the cooling design (24 points; the shipped runs
for the emulator families): koh with a GP, no, orthogonal or scaled
discrepancy; modular; koh_emulator.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import warnings
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

from conftest import COOLING, cooling_data  # noqa: E402
from stancal.sbc import simulation_based_calibration  # noqa: E402

SIMULATOR = COOLING / "simulator.stan"
FAMILIES = {
    "koh": dict(simulator=SIMULATOR, method="koh", discrepancy="gp"),
    "koh_none": dict(simulator=SIMULATOR, method="koh", discrepancy="none"),
    "koh_orthogonal": dict(simulator=SIMULATOR, method="koh", discrepancy="orthogonal"),
    "koh_scaled": dict(simulator=SIMULATOR, method="koh", discrepancy="scaled"),
    "modular": dict(method="modular", discrepancy="gp"),
    "koh_emulator": dict(method="koh_emulator", discrepancy="gp"),
}


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--family", nargs="+", default=list(FAMILIES), choices=list(FAMILIES))
    parser.add_argument("--sims", type=int, default=200)
    parser.add_argument("--draws-per-fit", type=int, default=100)
    args = parser.parse_args()
    path = Path(__file__).parent / "sbc.json"
    rows = json.loads(path.read_text()) if path.is_file() else {}
    for family in args.family:
        started = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            result = simulation_based_calibration(cooling_data(seed=7), simulations=args.sims,
                                                  draws_per_fit=args.draws_per_fit, seed=1, warmup=300,
                                                  **FAMILIES[family])
        rows[family] = {"simulations": args.sims, "draws_per_fit": args.draws_per_fit,
                        "p_values": {n: t.p_value for n, t in result.tests.items()},
                        "rejected": [n for n, t in result.tests.items() if t.rejected],
                        "failed_simulations": len(result.failed), "seconds": time.perf_counter() - started}
        path.write_text(json.dumps(rows, indent=2))
    print("| family | S | L | p-values | rejected | wall time |")
    print("|---|---|---|---|---|---|")
    for family, r in rows.items():
        p = ", ".join(f"{n} {v:.2f}" for n, v in r["p_values"].items())
        print(f"| {family} | {r['simulations']} | {r['draws_per_fit']} | {p} | {', '.join(r['rejected']) or 'none'} "
              f"| {r['seconds']:.0f} s |")


if __name__ == "__main__":
    main()
