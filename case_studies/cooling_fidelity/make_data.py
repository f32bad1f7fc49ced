"""Make the two-fidelity cooling case study's data (fixed seed, so the
shipped CSVs are reproducible): python case_studies/cooling_fidelity/make_data.py

A cup cools in a room at 20 deg C. The cheap simulator is Newton's law
(convection at rate k alone, closed form). The expensive one adds the
radiative and evaporative loss c (T - Ta)^2 that dominates at high
temperature (c known, 4e-4 per deg C per minute), and stands for a costly
solver: 150 cheap runs and 15 expensive ones are the budget. The
measurements come from the expensive simulator at k = 0.05 per minute with
0.4 deg C of noise, so no discrepancy is needed: the question is how well
theta is pinned when the expensive simulator is known only at 15 runs.
"""

from pathlib import Path

import numpy as np
import pandas as pd
from scipy.stats import qmc

AMBIENT = 20.0
K_TRUE = 0.05  # 1/min
K_BOUNDS = (0.02, 0.1)
C_LOSS = 4e-4  # 1/(deg C min): the loss the cheap simulator lacks
NOISE_SD = 0.4  # deg C
T_RANGE, T0_RANGE = (0.0, 60.0), (55.0, 95.0)


def newton(t, T0, k):
    """The cheap simulator (case_studies/cooling's newton)."""
    return AMBIENT + (T0 - AMBIENT) * np.exp(-k * t)


def with_loss(t, T0, k, c=C_LOSS):
    """The expensive simulator: the exact solution of dT/dt = -k (T - Ta) - c (T - Ta)^2
    (case_studies/cooling's reality, c fixed)."""
    u0 = T0 - AMBIENT
    decay = np.exp(-k * t)
    return AMBIENT + k * u0 * decay / (k + c * u0 * (1 - decay))


def design(n: int, seed: int) -> pd.DataFrame:
    """A Latin hypercube over (t, T0, k)."""
    u = qmc.LatinHypercube(d=3, seed=seed).random(n)
    lows, highs = np.array([T_RANGE[0], T0_RANGE[0], K_BOUNDS[0]]), np.array([T_RANGE[1], T0_RANGE[1], K_BOUNDS[1]])
    return pd.DataFrame(lows + (highs - lows) * u, columns=["t", "T0", "k"])


def runs(model, n: int, seed: int) -> pd.DataFrame:
    table = design(n, seed)
    table["temperature"] = model(table["t"], table["T0"], table["k"])
    return table.round(5)


def main(folder: Path = Path(__file__).parent) -> None:
    rng = np.random.default_rng(20261125)
    t = np.tile(np.linspace(4, 56, 14), 2)  # inside the 15 expensive runs (t from 2.2 to 57.4)
    T0 = np.repeat([65.0, 90.0], 14)
    physical = pd.DataFrame({"t": t.round(2), "T0": T0})
    physical["temperature"] = (with_loss(t, T0, K_TRUE) + rng.normal(0, NOISE_SD, t.size)).round(3)
    physical.to_csv(folder / "physical.csv", index=False)
    runs(newton, 150, 1).to_csv(folder / "runs_low.csv", index=False)
    runs(with_loss, 15, 2).to_csv(folder / "runs_high.csv", index=False)


if __name__ == "__main__":
    main()
