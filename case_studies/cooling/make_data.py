"""Make the cooling case study's data (fixed seed, so the shipped CSVs are
reproducible): python case_studies/cooling/make_data.py

Reality cools faster than Newton's law at high temperature: besides
convection (rate k) it loses heat by evaporation and radiation, modelled
here as a quadratic term c * (T - T_amb)^2 that the simulator lacks. The
variant simulator_quadratic_loss.stan has it; humidity and operator are
measured but play no part (decoys for the gap diagnosis).
"""

from pathlib import Path

import numpy as np
import pandas as pd

AMBIENT = 20.0
K_TRUE = 0.05  # 1/min
C_TRUE = 4e-4  # 1/(deg C min): the effect the simulator does not have
NOISE_SD = 0.4  # deg C


def newton(t, T0, k):
    return AMBIENT + (T0 - AMBIENT) * np.exp(-k * t)


def reality(t, T0, k=K_TRUE, c=C_TRUE):
    """Exact solution of dT/dt = -k (T - Ta) - c (T - Ta)^2."""
    u0 = T0 - AMBIENT
    decay = np.exp(-k * t)
    return AMBIENT + k * u0 * decay / (k + c * u0 * (1 - decay))


def main(folder: Path = Path(__file__).parent) -> None:
    rng = np.random.default_rng(20261122)
    t = np.tile(np.linspace(0, 60, 14)[1:], 3)
    T0 = np.repeat([60.0, 75.0, 90.0], 13)
    physical = pd.DataFrame({
        "t": t.round(2),
        "T0": T0,
        "humidity": rng.uniform(30, 70, t.size).round(1),  # measured, irrelevant here
        "temperature": (reality(t, T0) + NOISE_SD * rng.standard_normal(t.size)).round(3),
    })
    physical.to_csv(folder / "physical.csv", index=False)

    m = 60  # Latin hypercube of simulator runs over (t, T0, k)
    u = (np.column_stack([rng.permutation(m) for _ in range(3)]) + rng.uniform(size=(m, 3))) / m
    runs = pd.DataFrame({"t": 62 * u[:, 0], "T0": 55 + 40 * u[:, 1], "k": 0.01 + 0.19 * u[:, 2]})
    runs["temperature"] = newton(runs.t, runs.T0, runs.k)
    runs.round(5).to_csv(folder / "runs.csv", index=False)

    # drawn last so that the columns above stay as first shipped
    physical.insert(3, "operator", rng.choice(["ana", "ben", "chloe"], size=t.size))  # irrelevant
    physical.to_csv(folder / "physical.csv", index=False)


if __name__ == "__main__":
    main()
