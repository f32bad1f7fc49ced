"""Regenerate the ball-drop example of SEPIA (Gattiker et al., LANL; the
"Ball Drop with Varying Radii" example, examples/Ball_Drop in
github.com/lanl/SEPIA) from its published physics and design:
python case_studies/ball_drop/make_data.py

Balls of radius R = 0.1, 0.2 and 0.4 m are dropped from a tower; each drop
is timed as it passes 5, 10, 15 and 20 m (a vector output over the
distance fallen h). Reality has quadratic drag,
    d2h/dt2 = g - (C / R) (dh/dt)^2,  h(t) = (R / C) ln cosh(sqrt(g C / R) t),
with C = 0.1 / (4 pi / 3) and g = 9.8; each time is read with an error
0.01 U(0, 1), as the example draws it. The simulator has linear drag,
    d2h/dt2 = g - (C / R) dh/dt,  h(t) = (g R / C) t - (g R^2 / C^2) (1 - exp(-C t / R)),
and returns the time at 16 heights 1.5, 3, ..., 24 m; its 25 runs are the
example's Latin hypercube over R in [0.05, 0.45] and C in [0.05, 0.25].
The simulator is wrong by construction (linear for quadratic drag), so the
discrepancy, not C alone, carries the truth.
"""

from pathlib import Path

import numpy as np
import pandas as pd
from scipy.optimize import brentq

G = 9.8
C_TRUE = 0.1 / (4 * np.pi / 3)
RADII = np.array([0.1, 0.2, 0.4])
FIELD_HEIGHTS = np.linspace(5, 20, 4)
SIM_HEIGHTS = np.arange(1.5, 25, 1.5)
READING_ERROR = 0.01  # times are read late by 0.01 U(0, 1) s
DESIGN = np.array([  # the example's 25-run design on [0, 1]^2 (R, C)
    [0.1239, 0.8024], [0.8738, 0.6473], [0.6140, 0.3337], [0.8833, 0.4783], [0.9946, 0.0548],
    [0.1178, 0.9382], [0.1805, 0.2411], [0.6638, 0.2861], [0.2939, 0.1208], [0.2451, 0.2397],
    [0.4577, 0.5696], [0.4377, 0.8874], [0.0737, 0.7384], [0.6931, 0.8683], [0.4901, 0.7070],
    [0.5953, 0.9828], [0.7506, 0.1009], [0.7783, 0.4225], [0.8333, 0.5318], [0.3987, 0.6312],
    [0.2021, 0.4990], [0.3495, 0.3680], [0.9411, 0.7935], [0.0198, 0.0218], [0.5440, 0.1925]])


def fallen_true(t, C, R):
    return R / C * np.log(np.cosh(np.sqrt(G * C / R) * t))


def fallen_simulated(t, C, R):
    b = C / R
    return G * t / b - G / b**2 * (1 - np.exp(-b * t))


def time_to_fall(h, fallen, C, R):
    """The time at which ``fallen`` reaches h (fallen is increasing in t)."""
    return brentq(lambda t: fallen(t, C, R) - h, 1e-9, 60.0, xtol=1e-12)


def true_times(heights, R):
    return np.array([time_to_fall(h, fallen_true, C_TRUE, R) for h in heights])


def main(folder: Path = Path(__file__).parent) -> None:
    rng = np.random.default_rng(2020)
    rows = []
    for R in RADII:
        times = true_times(FIELD_HEIGHTS, R) + READING_ERROR * rng.uniform(size=len(FIELD_HEIGHTS))
        rows.append(pd.DataFrame({"ball": f"R{R:g}", "R": R, "h": FIELD_HEIGHTS, "time": times}))
    pd.concat(rows).round(6).to_csv(folder / "physical.csv", index=False)
    R_runs, C_runs = 0.05 + 0.4 * DESIGN[:, 0], 0.05 + 0.2 * DESIGN[:, 1]
    runs = [pd.DataFrame({"run": r, "R": R, "C": C, "h": SIM_HEIGHTS,
                          "time": [time_to_fall(h, fallen_simulated, C, R) for h in SIM_HEIGHTS]})
            for r, (R, C) in enumerate(zip(R_runs, C_runs, strict=False))]
    pd.concat(runs).round(6).to_csv(folder / "runs.csv", index=False)


if __name__ == "__main__":
    main()
