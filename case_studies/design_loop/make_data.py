"""Writes physical.csv (the real fin, measured with 0.3 deg C of noise) and
runs.csv (40 simulator runs: a Latin hypercube of all seven inputs and
theta (2^7 corners exceed the budget), its first two rows moved to the
inputs' opposite corners so the runs span the measured range)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
from scipy.stats import qmc
from simulator import THETA, fin_temperature, measured

HERE = Path(__file__).resolve().parent
NOISE_SD = 0.3  # deg C
INITIAL_RUNS = 40
INPUTS = {"x": (0.0, 0.3), "T_b": (60.0, 120.0)}


def physical(seed: int = 11) -> pd.DataFrame:
    rng = np.random.default_rng(seed)
    positions = np.linspace(0.0, 0.3, 7)
    rows = [pd.DataFrame({"x": positions, "T_b": T_b, "T": measured(positions, T_b)}) for T_b in (60, 75, 90, 105, 120)]
    table = pd.concat(rows, ignore_index=True)
    table["T"] += rng.normal(0, NOISE_SD, len(table))
    return table.round(4)


def initial_runs(count: int = INITIAL_RUNS, seed: int = 12) -> pd.DataFrame:
    box = {**INPUTS, **THETA}
    unit = qmc.LatinHypercube(d=len(box), seed=seed).random(count)
    table = pd.DataFrame(qmc.scale(unit, *zip(*box.values(), strict=True)), columns=list(box))
    table.loc[:1, "x"] = [0.0, 0.3]  # the runs span the measured positions
    table.loc[:1, "T_b"] = [60.0, 120.0]
    table["T"] = fin_temperature(table)
    return table


if __name__ == "__main__":
    physical().to_csv(HERE / "physical.csv", index=False)
    initial_runs().to_csv(HERE / "runs.csv", index=False)
