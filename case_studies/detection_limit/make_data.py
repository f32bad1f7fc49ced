"""Lab concentrations with the usual reporting limits: below the limit of
detection (1.0 mg/L) the lab reports "< 1.0" (left-censored); between it and
the limit of quantification (1.5 mg/L) it reports "detected, not quantified"
(interval-censored); above the calibrated range (7 mg/L) it reports "> 7"
(right-censored). About a third of the rows are censored. Writes physical.csv:
an empty concentration with the bounds in lower/upper marks a censored row."""

from pathlib import Path

import numpy as np
import pandas as pd

K_TRUE = 0.15  # 1/h
NOISE_SD = 0.5  # mg/L
DETECTION_LIMIT, QUANTIFICATION_LIMIT, UPPER_LIMIT = 1.0, 1.5, 7.0


def simulator(t, c0, k):
    return c0 * np.exp(-k * t)


def censor(values: np.ndarray) -> pd.DataFrame:
    """The lab's report of true values: exact, or a range."""
    value = values.copy()
    lower = np.full(values.size, np.nan)
    upper = np.full(values.size, np.nan)
    left = values < DETECTION_LIMIT
    between = (values >= DETECTION_LIMIT) & (values < QUANTIFICATION_LIMIT)
    right = values > UPPER_LIMIT
    value[left | between | right] = np.nan
    upper[left] = DETECTION_LIMIT
    lower[between], upper[between] = DETECTION_LIMIT, QUANTIFICATION_LIMIT
    lower[right] = UPPER_LIMIT
    return pd.DataFrame({"concentration": value, "lower": lower, "upper": upper})


def measurements(seed: int) -> pd.DataFrame:
    """Samples at 30 times over 14 h from three doses, as the lab reports them."""
    rng = np.random.default_rng(seed)
    t, c0 = np.meshgrid(np.linspace(0.5, 14, 30), [4.0, 6.0, 8.0])
    t, c0 = t.ravel(), c0.ravel()
    measured = simulator(t, c0, K_TRUE) + NOISE_SD * rng.standard_normal(t.size)
    return pd.concat([pd.DataFrame({"t": t, "c0": c0}), censor(measured)], axis=1).round(4)


def naive_frames(frame: pd.DataFrame) -> dict[str, pd.DataFrame]:
    """What people do without a censored likelihood: drop the censored rows,
    or impute them at the limit (an interval at its midpoint)."""
    value, low, high = (frame[c].to_numpy() for c in ("concentration", "lower", "upper"))
    imputed = np.where(np.isnan(value),
                       np.where(np.isnan(low), high, np.where(np.isnan(high), low, (low + high) / 2)), value)
    return {"drop": frame[frame.concentration.notna()], "impute": frame.assign(concentration=imputed)}


def main(folder: Path = Path(__file__).parent) -> None:
    measurements(seed=11).to_csv(folder / "physical.csv", index=False)


if __name__ == "__main__":
    main()
