"""Make the stochastic_cooling case study's data (fixed seed, so the shipped
CSVs are reproducible): python case_studies/stochastic_cooling/make_data.py

A stochastic simulator of a cooling cup (a Monte Carlo model of the cup's
turbulent surroundings, say): each run returns Newton's law with the heat
transfer rate k plus its own run-to-run scatter, whose sd grows tenfold
over the run, sd(t) = 0.2 * 10^(t / 60 min) deg C. Its mean is Newton's law, so
the simulator's mean at the true k = 0.05 1/min is the truth, with no
discrepancy. runs.csv: 60 Latin-hypercube settings of (t, T0, k), each run
5 times (300 runs). physical.csv: the true process measured at 10 times
from 2 to 60 min from two start temperatures, two cups each, sd 0.1 deg C
(40 readings); heldout.csv
holds as many readings again, never fitted, and heldout_new.csv readings at
settings the fit has none at (start temperatures 70 and 80 deg C, times
halfway between the fitted ones), where the emulator's misfit is not
conditioned on any reading (compare.py scores the bands at both).
"""

from pathlib import Path

import numpy as np
import pandas as pd
from scipy.stats import qmc

AMBIENT = 20.0
K_TRUE = 0.05  # 1/min
K_BOUNDS = (0.02, 0.1)  # 1/min, the config's prior
T_RANGE, T0_RANGE = (0.0, 64.0), (55.0, 95.0)  # min, deg C: the runs cover the readings' 2-60 min
SETTINGS, REPLICATES = 60, 5  # run settings, runs of each
TIMES = np.linspace(2, 60, 10)  # min
STARTS = (60.0, 90.0)  # deg C
MEASUREMENT_SD = 0.1  # deg C
READINGS = 2  # cups per (t, T0): their spread tells the measurement noise from the emulator's error
NEW_TIMES = 0.5 * (TIMES[1:] + TIMES[:-1])  # min: held out, between the fitted times
NEW_STARTS = (70.0, 80.0)  # deg C: held out, between the fitted start temperatures


def newton(t, T0, k):
    return AMBIENT + (T0 - AMBIENT) * np.exp(-k * t)


def intrinsic_sd(t):
    """The simulator's own run-to-run sd (deg C): 0.2 at t = 0, 2.0 at t = 60 min."""
    return 0.2 * 10 ** (np.asarray(t) / 60.0)


def runs(rng: np.random.Generator) -> pd.DataFrame:
    unit = qmc.LatinHypercube(d=3, seed=rng).random(SETTINGS)
    low, high = np.array([T_RANGE[0], T0_RANGE[0], K_BOUNDS[0]]), np.array([T_RANGE[1], T0_RANGE[1], K_BOUNDS[1]])
    t, T0, k = (np.repeat(c, REPLICATES) for c in qmc.scale(unit, low, high).round(5).T)
    temperature = newton(t, T0, k) + intrinsic_sd(t) * rng.standard_normal(t.size)
    return pd.DataFrame({"t": t, "T0": T0, "k": k, "temperature": temperature.round(4)})


def readings(rng: np.random.Generator, times=TIMES, starts=STARTS) -> pd.DataFrame:
    t, T0 = (np.repeat(a.ravel(), READINGS) for a in np.meshgrid(times, starts))
    temperature = newton(t, T0, K_TRUE) + MEASUREMENT_SD * rng.standard_normal(t.size)
    return pd.DataFrame({"t": t.round(3), "T0": T0, "temperature": temperature.round(4)})


def main(folder: Path = Path(__file__).parent) -> None:
    rng = np.random.default_rng(20261126)
    runs(rng).to_csv(folder / "runs.csv", index=False)
    readings(rng).to_csv(folder / "physical.csv", index=False)
    readings(rng).to_csv(folder / "heldout.csv", index=False)
    # drawn last, so the files above stay as they were
    readings(rng, NEW_TIMES, NEW_STARTS).to_csv(folder / "heldout_new.csv", index=False)


if __name__ == "__main__":
    main()
