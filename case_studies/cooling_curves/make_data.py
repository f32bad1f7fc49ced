"""Make the cooling-curves case study's data (fixed seed, so the shipped
CSVs are reproducible): python case_studies/cooling_curves/make_data.py

A vector output: each simulator run returns a whole cooling curve,
Newton's law T(t) = Ta + (T0 - Ta) exp(-k t) on 31 times from 0 to 60 min.
Six cool-downs were logged, each by its own probe at its own irregular
times (ragged: not on the runs' grid), each probe reading off by an
offset of its own (a per-experiment parameter), with a known noise sd per
reading. The probes follow the simulator exactly at the truth below: the
calibration's intervals should cover it.
"""

from pathlib import Path

import numpy as np
import pandas as pd

K_TRUE, TA_TRUE = 0.045, 21.3  # 1/min, deg C
GRID = np.linspace(0, 60, 31)
RUNS = 60


def newton(t, T0, k, Ta):
    return Ta + (T0 - Ta) * np.exp(-k * t)


def main(folder: Path = Path(__file__).parent) -> None:
    rng = np.random.default_rng(20261124)
    offsets = rng.uniform(-0.6, 0.6, 6)
    rows = []
    for e, offset in enumerate(offsets):
        t = np.sort(rng.uniform(0, 60, rng.integers(8, 16)))
        T0, sd = rng.uniform(60, 90), rng.choice([0.15, 0.3])
        rows.append(pd.DataFrame({"cooldown": f"cup{e + 1}", "T0": round(T0, 2), "t": t.round(2), "sd": sd,
                                  "temperature": newton(t, T0, K_TRUE, TA_TRUE) + offset
                                  + sd * rng.standard_normal(t.size)}))
    pd.concat(rows).round(4).to_csv(folder / "physical.csv", index=False)
    pd.DataFrame({"cooldown": [f"cup{e + 1}" for e in range(6)], "offset": offsets.round(4)}).to_csv(
        folder / "truth_offsets.csv", index=False)

    u = (np.column_stack([rng.permutation(RUNS) for _ in range(4)]) + rng.uniform(size=(RUNS, 4))) / RUNS
    settings = pd.DataFrame({"run": np.arange(RUNS), "T0": 55 + 40 * u[:, 0], "k": 0.01 + 0.09 * u[:, 1],
                             "Ta": 15 + 10 * u[:, 2], "offset": -1 + 2 * u[:, 3]})
    runs = settings.loc[settings.index.repeat(len(GRID))].reset_index(drop=True)
    runs["t"] = np.tile(GRID, RUNS)
    runs["temperature"] = newton(runs.t, runs.T0, runs.k, runs.Ta) + runs.offset
    runs.round(5).to_csv(folder / "runs.csv", index=False)


if __name__ == "__main__":
    main()
