"""Detector counts with an effect the simulator lacks: the detector's finite
size. The point-detector inverse-square law overstates the solid angle close
to the source; the exact solid angle of a disc of radius R = 0.3 m makes the
true count rate lower there (a discrepancy that depends on d alone).
Writes physical.csv (Poisson counts) and runs.csv (simulator means)."""

from pathlib import Path

import numpy as np
import pandas as pd

from stancal.problem.design import latin_hypercube_with_corners

MU_TRUE = 0.35  # 1/cm
DETECTOR_RADIUS = 0.3  # m
SOURCE = 2000.0  # counts per period at 1 m without shield (point detector)


def simulator(d, s, mu):
    return SOURCE * np.exp(-mu * s) / d**2


def solid_angle_factor(d):
    """Exact solid angle of the disc over the point-detector approximation."""
    exact = 2 * np.pi * (1 - d / np.sqrt(d**2 + DETECTOR_RADIUS**2))
    point = np.pi * DETECTOR_RADIUS**2 / d**2
    return exact / point


def true_mean(d, s):
    return simulator(d, s, MU_TRUE) * solid_angle_factor(d)


def main(folder: Path = Path(__file__).parent) -> None:
    rng = np.random.default_rng(2024)
    d, s = np.meshgrid([0.5, 0.75, 1.0, 1.5, 2.0, 2.5, 3.0], [0.0, 1.0, 2.5, 4.0, 5.0])
    d, s = d.ravel(), s.ravel()
    counts = rng.poisson(true_mean(d, s))
    pd.DataFrame({"d": d, "s": s, "counts": counts}).to_csv(folder / "physical.csv", index=False)
    runs = pd.DataFrame(latin_hypercube_with_corners([0.5, 0.0, 0.05], [3.0, 5.0, 1.0], runs=60, seed=5),
                        columns=["d", "s", "mu"]).round(4)
    runs["counts"] = simulator(runs.d, runs.s, runs.mu).round(4)
    runs.to_csv(folder / "runs.csv", index=False)


if __name__ == "__main__":
    main()
