"""Make the hetero_noise case study's data (fixed seed, so the shipped CSVs
are reproducible): python case_studies/hetero_noise/make_data.py

Cups cooling by Newton's law (k = 0.05 1/min, the cooling case's simulator,
exact here), measured at 10 times from 2 to 60 min, from two start
temperatures, 4 cups per setting: 80 readings with replicates. The readings'
scatter grows tenfold over the run, sd(t) = 0.1 * 10^((t - 2) / 58) deg C
(a probe whose contact degrades as it heats). heldout.csv holds 4 more cups
per setting, never fitted: the replicates whose coverage compare.py scores.
"""

from pathlib import Path

import numpy as np
import pandas as pd

AMBIENT = 20.0
K_TRUE = 0.05  # 1/min
TIMES = np.linspace(2, 60, 10)  # min
STARTS = (60.0, 90.0)  # deg C
REPLICATES = 4  # cups per (t, T0), fitted; as many again held out


def newton(t, T0, k=K_TRUE):
    return AMBIENT + (T0 - AMBIENT) * np.exp(-k * t)


def noise_sd(t):
    """The readings' true sd (deg C): 0.1 at t = 2 min, 1.0 at t = 60 min."""
    return 0.1 * 10 ** ((np.asarray(t) - TIMES[0]) / (TIMES[-1] - TIMES[0]))


def readings(rng: np.random.Generator) -> pd.DataFrame:
    t, T0 = (a.ravel() for a in np.meshgrid(TIMES, STARTS))
    t, T0 = np.repeat(t, REPLICATES), np.repeat(T0, REPLICATES)
    temperature = newton(t, T0) + noise_sd(t) * rng.standard_normal(t.size)
    return pd.DataFrame({"t": t.round(3), "T0": T0, "temperature": temperature.round(4)})


def main(folder: Path = Path(__file__).parent) -> None:
    rng = np.random.default_rng(20261126)
    readings(rng).to_csv(folder / "physical.csv", index=False)
    readings(rng).to_csv(folder / "heldout.csv", index=False)


if __name__ == "__main__":
    main()
