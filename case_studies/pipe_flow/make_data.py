"""Make the pipe-flow case study's data (fixed seed, so the shipped CSVs are
reproducible): python case_studies/pipe_flow/make_data.py

Water flows through a 10 mm pipe of length L at mean velocity v. The
simulator is Hagen-Poiseuille friction, dp = 32 mu L v / d^2, with the
viscosity mu to calibrate. The test rig also has fittings (an inlet, a
valve, two bends) whose minor loss K rho v^2 / 2 the simulator lacks: an
effect linear in v^2, the formula candidate "I(v**2)". Pipe batch and room
humidity are measured but play no part (decoys).
"""

from pathlib import Path

import numpy as np
import pandas as pd

DIAMETER = 0.01  # m
DENSITY = 1000.0  # kg/m^3
MU_TRUE = 1.5  # mPa s
MINOR_LOSS_K = 3.0  # sum of the fittings' loss coefficients: the withheld effect
NOISE_SD = 0.02  # kPa


def poiseuille(v, length, mu):
    """Friction pressure drop in kPa (v in m/s, length in m, mu in mPa s)."""
    return 32 * mu * 1e-3 * length * v / DIAMETER**2 / 1000


def minor_loss(v):
    return MINOR_LOSS_K * DENSITY * v**2 / 2 / 1000


def reality(v, length):
    return poiseuille(v, length, MU_TRUE) + minor_loss(v)


def main(folder: Path = Path(__file__).parent) -> None:
    rng = np.random.default_rng(20261123)
    n = 40
    v = rng.uniform(0.05, 0.5, n)
    length = rng.choice([1.0, 2.5, 5.0, 7.5, 10.0], n)
    physical = pd.DataFrame({
        "v": v.round(4),
        "L": length,
        "batch": rng.choice(["A", "B", "C"], n),
        "humidity": rng.uniform(30, 70, n).round(1),
    })
    physical["dp"] = (reality(physical.v, physical.L) + NOISE_SD * rng.standard_normal(n)).round(4)
    physical.to_csv(folder / "physical.csv", index=False)

    m = 60  # Latin hypercube of simulator runs over (v, L, mu)
    u = (np.column_stack([rng.permutation(m) for _ in range(3)]) + rng.uniform(size=(m, 3))) / m
    runs = pd.DataFrame({"v": 0.04 + 0.47 * u[:, 0], "L": 0.8 + 9.4 * u[:, 1], "mu": 0.5 + 3.5 * u[:, 2]})
    runs["dp"] = poiseuille(runs.v, runs.L, runs.mu)
    runs.round(5).to_csv(folder / "runs.csv", index=False)


if __name__ == "__main__":
    main()
