"""Make the cooling-in-a-draught case study's data (fixed seed, so the
shipped CSVs are reproducible): python case_studies/cooling_wind/make_data.py

A vector output with a withheld effect. Eight cups cool down, each logged at
its own irregular times with a known noise sd. The simulator is Newton's
law T(t) = Ta + (T0 - Ta) exp(-k t). The real cups also sit in a draught of
their own: forced convection raises the cooling rate to k (1 + c wind),
which the simulator leaves out. The log also has each cup's room humidity
and probe depth, which do nothing (decoys). `stancal gap` should find the
draught: the gap sits at middle times in the windy cups, the
forced-convection variant ranks first and removes most of the gap, and
k's error shrinks once it is added.
"""

from pathlib import Path

import numpy as np
import pandas as pd

K_TRUE, TA_TRUE, C_TRUE = 0.045, 21.3, 0.6  # 1/min, deg C, per (m/s)
CUPS = 8
SD = 0.2  # deg C, every reading
GRID = np.linspace(0, 60, 31)  # the runs' times, min
RUNS = 60


def cooling(t, T0, k, Ta):
    return Ta + (T0 - Ta) * np.exp(-k * t)


def main(folder: Path = Path(__file__).parent) -> None:
    rng = np.random.default_rng(20261125)
    rows = []
    for e in range(CUPS):
        t = np.sort(rng.uniform(0, 60, rng.integers(6, 10)))
        T0, wind = rng.uniform(60, 90), (e + rng.uniform()) * 1.5 / CUPS  # calm to 1.5 m/s
        k = K_TRUE * (1 + C_TRUE * wind)
        rows.append(pd.DataFrame({
            "cooldown": f"cup{e + 1:02d}", "T0": round(T0, 2), "wind": round(wind, 3),
            "humidity": round(rng.uniform(30, 70), 1), "depth": round(rng.uniform(5, 15), 1),
            "t": t.round(2), "sd": SD, "temperature": cooling(t, T0, k, TA_TRUE) + SD * rng.standard_normal(t.size)}))
    pd.concat(rows).round(4).to_csv(folder / "physical.csv", index=False)
    # 60 runs of the simulator (Newton's law, no draught) for method modular
    u = (np.column_stack([rng.permutation(RUNS) for _ in range(3)]) + rng.uniform(size=(RUNS, 3))) / RUNS
    settings = pd.DataFrame({"run": np.arange(RUNS), "T0": 55 + 40 * u[:, 0], "k": 0.01 + 0.14 * u[:, 1],
                             "Ta": 15 + 10 * u[:, 2]})
    runs = settings.loc[settings.index.repeat(len(GRID))].reset_index(drop=True)
    runs["t"] = np.tile(GRID, RUNS)
    runs["temperature"] = cooling(runs.t, runs.T0, runs.k, runs.Ta)
    runs.round(5).to_csv(folder / "runs.csv", index=False)


if __name__ == "__main__":
    main()
