"""Two instruments measure the same cooling cups (docs/noise.md, "Biased
sources"): a thermocouple, the reference, and an infrared camera that reads
warm in the middle of the run, a smooth bias over the time t. The truth is
Newton's law at k = 0.05 1/min (no discrepancy); each instrument has its own
noise sd. python case_studies/two_instruments/make_data.py writes physical.csv
(fitted) and heldout.csv (new readings at the same settings, never fitted)."""

from pathlib import Path

import numpy as np
import pandas as pd

HERE = Path(__file__).parent
K_TRUE = 0.05  # 1/min
T_AMBIENT = 20.0  # deg C
START = (60.0, 90.0)  # deg C: the cups' start temperatures
NOISE_SD = {"thermocouple": 0.2, "camera": 0.5}  # deg C, each instrument's own
# minutes: the reference reads every 6 min from 3, the camera every 3 min from 2 (three readings in four are its)
TIMES = {"thermocouple": np.arange(3.0, 60.0, 6.0), "camera": np.arange(2.0, 61.0, 3.0)}


def newton(t, start, k=K_TRUE):
    """The truth: Newton's law of cooling (the cooling case's simulator)."""
    return T_AMBIENT + (np.asarray(start) - T_AMBIENT) * np.exp(-k * np.asarray(t))


def camera_bias(t):
    """The camera's bias (deg C): warm by up to 1.5 deg C around t = 25 min,
    a smooth hump over the run, zero at its ends."""
    return 1.5 * np.exp(-0.5 * ((np.asarray(t) - 25.0) / 10.0) ** 2)


def readings(seed: int) -> pd.DataFrame:
    """Each instrument's readings of both cups at its times."""
    rng = np.random.default_rng(seed)
    parts = []
    for source, times in TIMES.items():
        t = np.tile(times, len(START))
        start = np.repeat(START, len(times))
        bias = camera_bias(t) if source == "camera" else 0.0
        value = newton(t, start) + bias + NOISE_SD[source] * rng.standard_normal(len(t))
        parts.append(pd.DataFrame({"t": t, "T0": start, "instrument": source, "temperature": value.round(3)}))
    return pd.concat(parts, ignore_index=True)


def main() -> None:
    readings(1).to_csv(HERE / "physical.csv", index=False)
    readings(2).to_csv(HERE / "heldout.csv", index=False)


if __name__ == "__main__":
    main()
