"""Make the sensor-log case study's data (fixed seed, so the shipped CSVs are
reproducible): python case_studies/sensor_log/make_data.py

A temperature logger records 25 cool-downs of a probe, 200 readings each:
N = 5,000 physical points. The probe follows the simulator (Newton's law
towards an unknown room temperature) at k = 0.045 1/min, Ta = 21.3 deg C,
with logger noise of sd 0.3 deg C; there is no discrepancy to find, so
theta's interval must cover the truth. 5,000 simulator runs fill a Latin
hypercube over (t, T0, k, Ta) for the emulator path.
"""

from pathlib import Path

import numpy as np
import pandas as pd

K_TRUE, TA_TRUE = 0.045, 21.3
NOISE_SD = 0.3  # deg C
COOL_DOWNS, READINGS, RUNS = 25, 200, 5000


def newton(t, T0, k, ambient):
    return ambient + (T0 - ambient) * np.exp(-k * t)


def main(folder: Path = Path(__file__).parent) -> None:
    rng = np.random.default_rng(20261124)
    T0 = np.repeat(rng.uniform(55, 95, COOL_DOWNS), READINGS)
    t = np.tile(np.sort(rng.uniform(0, 60, READINGS)), COOL_DOWNS)
    physical = pd.DataFrame({
        "t": t.round(3), "T0": T0.round(2),
        "temperature": (newton(t, T0, K_TRUE, TA_TRUE) + NOISE_SD * rng.standard_normal(t.size)).round(3),
    })
    physical.to_csv(folder / "physical.csv", index=False)

    u = (np.column_stack([rng.permutation(RUNS) for _ in range(4)]) + rng.uniform(size=(RUNS, 4))) / RUNS
    runs = pd.DataFrame({"t": 60 * u[:, 0], "T0": 55 + 40 * u[:, 1], "k": 0.01 + 0.09 * u[:, 2],
                         "Ta": 15 + 10 * u[:, 3]})
    runs["temperature"] = newton(runs.t, runs.T0, runs.k, runs.Ta)
    runs.round(5).to_csv(folder / "runs.csv", index=False)


if __name__ == "__main__":
    main()
