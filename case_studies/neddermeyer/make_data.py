"""Regenerate SEPIA's Neddermeyer implosion example (examples/Neddermeyer in
github.com/lanl/SEPIA; Higdon, Gattiker, Williams & Rightley 2008, "Computer
model calibration using high-dimensional output", JASA 103, section 3) from
its physics and design: python case_studies/neddermeyer/make_data.py

A steel cylinder (outer radius R1 = 1.5 in, inner radius lam R1, lam = 2/3,
density rho = 7.5 g/cm^3) is imploded by high explosive. Neddermeyer's
(1943) model of his experiment 10 gives the scaled inner radius y = r/R1
through
    dy/dt = -sqrt(2 / (R1^2 f(y)) (v0^2 / 2 - s g(y) / (2 rho))),
    f(y) = y^2 / (1 - lam^2) ln((y^2 + 1 - lam^2) / y^2),
    g(y) = (y^2 ln y^2 - (y^2 + 1 - lam^2) ln(y^2 + 1 - lam^2) - lam^2 ln lam^2) / (1 - lam^2),
    v0 = m sqrt(2 u0 / (1 + m)),
with m the mass ratio of explosive to steel (the input x), s the steel's
yield stress and u0 the explosive's energy per gram (theta); the example
integrates it by Euler steps of 10 ns from y = lam, as here.

Runs: the example's 36-run Latin hypercube over m in 0.32 [0.5, 1.15] and
s, u0 each within 10 % of Neddermeyer's values (s0 = 2.052 GPa, u0 = 1.65
MJ/kg), each returning the inner radius over 22 times (0 to 50 us) x 26
angles (0 to 2 pi; the simulated implosion is round, so it is constant in
angle). Experiments: m = 0.32, 0.17 and 0.36 at the nominal theta, the
radius read at 16 angles at times (15, 27, 45), (45) and (25, 45) us: 96
values off the runs' grid, each with N(0, 0.01 cm) error and no
discrepancy.
"""

from pathlib import Path

import numpy as np
import pandas as pd

R1 = 1.5 * 2.54  # cm
LAM = 2 / 3
RHO = 7.5  # g/cm^3
YIELD_STRESS = 3e5 * 6.84e4 / 1e10  # GPa (3e5 lb/in^2 in dyn/cm^2, / 1e10)
HE_ENERGY = 1.65  # MJ/kg (1.65e10 erg/g)
MASS_RATIO = 0.32  # explosive to steel, experiment 10
THETA_BOUNDS = {"yield_stress": (0.9 * YIELD_STRESS, 1.1 * YIELD_STRESS),
                "he_energy": (0.9 * HE_ENERGY, 1.1 * HE_ENERGY)}
MASS_RATIO_BOUNDS = (0.5 * MASS_RATIO, 1.15 * MASS_RATIO)
NOISE_SD = 0.01  # cm
SIM_TIMES = np.linspace(0, 50, 22)  # us
SIM_ANGLES = np.linspace(0, 2 * np.pi, 26)
OBS_ANGLES = np.arange(16) * 2 * np.pi / 16
EXPERIMENTS = {"m0.32": (0.32, [15.0, 27.0, 45.0]), "m0.17": (0.17, [45.0]), "m0.36": (0.36, [25.0, 45.0])}
DT = 1e-8  # s: the example's Euler step
STEPS = 8000
DESIGN = np.array([  # the example's 36-run design on [0, 1]^3: (mass ratio, yield stress, HE energy)
    [0.7714, 0.4286, 0.0286], [0.3714, 0.1143, 0.7143], [0.1714, 0.4571, 0.8857], [0.3429, 0.6000, 0.8000],
    [0.8000, 0.6286, 0.4000], [0.7429, 0.5429, 0.0000], [0.6571, 1.0000, 0.6286], [0.2857, 0.0000, 0.4571],
    [0.5143, 0.9429, 0.2286], [0.6857, 0.3143, 0.6571], [0.8286, 0.2000, 1.0000], [0.9714, 0.3429, 0.6000],
    [0.4000, 0.8000, 0.2000], [0.5429, 0.2857, 0.2857], [0.9143, 0.8857, 0.2571], [0.0571, 0.0286, 0.0857],
    [0.1143, 0.5714, 0.7429], [0.2000, 0.2286, 0.3714], [0.4571, 0.9143, 0.3429], [0.6286, 0.7143, 0.6857],
    [0.0000, 0.8286, 0.9429], [0.8857, 0.0857, 0.9714], [0.2286, 0.0571, 0.5714], [0.7143, 0.1714, 0.8571],
    [0.2571, 0.4857, 0.1429], [0.5714, 0.4000, 0.8286], [0.9429, 0.6857, 0.4857], [0.4857, 0.1429, 0.1143],
    [1.0000, 0.8571, 0.9143], [0.6000, 0.6571, 0.5143], [0.1429, 0.7429, 0.5429], [0.8571, 0.2571, 0.0571],
    [0.3143, 0.3714, 0.4286], [0.4286, 0.7714, 0.7714], [0.0286, 0.9714, 0.3143], [0.0857, 0.5143, 0.1714]])


def _f(y):
    return y**2 / (1 - LAM**2) * np.log((y**2 + 1 - LAM**2) / y**2)


def _g(y):
    return (y**2 * np.log(y**2) - (y**2 + 1 - LAM**2) * np.log(y**2 + 1 - LAM**2)
            - LAM**2 * np.log(LAM**2)) / (1 - LAM**2)


def inner_radius(times_us, mass_ratio, yield_stress, he_energy):
    """Inner radius (cm) at ``times_us`` for arrays of settings (broadcast
    together): Neddermeyer's equation by the example's Euler steps, all
    settings at once. Returns (settings, times)."""
    m, s, u0 = np.broadcast_arrays(*(np.atleast_1d(np.asarray(a, float)) for a in (mass_ratio, yield_stress,
                                                                                   he_energy)))
    s_cgs, u0_cgs = s * 1e10, u0 * 1e10  # dyn/cm^2, erg/g
    v0 = m * np.sqrt(2 * u0_cgs / (1 + m))
    # the example's 8000 steps, or as many as the latest time needs (the same values, sooner)
    steps = min(STEPS, int(np.ceil(np.max(times_us) / (DT * 1e6))) + 2)
    path = np.empty((steps, m.size))
    y = np.full(m.size, LAM)
    path[0] = y
    for i in range(1, steps):
        # a cylinder that has closed (y = 0) stays closed: f and g are evaluated where it is open only
        open_ = y > 0
        at = np.where(open_, y, LAM)
        energy = np.maximum(v0**2 / 2 - s_cgs * _g(at) / (2 * RHO), 0.0)
        y = np.where(open_, np.maximum(y - np.sqrt(2 / (R1**2 * _f(at)) * energy) * DT, 0.0), 0.0)
        path[i] = y
    clock = np.arange(steps) * DT * 1e6  # us
    return R1 * np.column_stack([np.interp(times_us, clock, path[:, j]) for j in range(m.size)]).T


def runs_table(design: np.ndarray = DESIGN) -> pd.DataFrame:
    """One row per (run, time, angle): the design scaled to its ranges."""
    low_m, high_m = MASS_RATIO_BOUNDS
    (low_s, high_s), (low_u, high_u) = THETA_BOUNDS.values()
    m = low_m + (high_m - low_m) * design[:, 0]
    s = low_s + (high_s - low_s) * design[:, 1]
    u0 = low_u + (high_u - low_u) * design[:, 2]
    radius = inner_radius(SIM_TIMES, m, s, u0)
    time, angle = np.meshgrid(SIM_TIMES, SIM_ANGLES, indexing="ij")
    return pd.concat([pd.DataFrame({"run": r, "mass_ratio": m[r], "yield_stress": s[r], "he_energy": u0[r],
                                    "time": time.ravel(), "angle": angle.ravel(),
                                    "radius": np.repeat(radius[r], len(SIM_ANGLES))})
                      for r in range(len(design))], ignore_index=True)


def physical_table(seed: int = 2008) -> pd.DataFrame:
    """One row per measured value: the three experiments at the nominal theta."""
    rng = np.random.default_rng(seed)
    rows = []
    for name, (m, times) in EXPERIMENTS.items():
        radius = inner_radius(np.array(times), m, YIELD_STRESS, HE_ENERGY)[0]
        time, angle = np.repeat(times, len(OBS_ANGLES)), np.tile(OBS_ANGLES, len(times))
        rows.append(pd.DataFrame({"shot": name, "mass_ratio": m, "time": time, "angle": angle,
                                  "radius": np.repeat(radius, len(OBS_ANGLES))
                                  + NOISE_SD * rng.standard_normal(len(time))}))
    return pd.concat(rows, ignore_index=True)


def main(folder: Path = Path(__file__).parent) -> None:
    physical_table().round(6).to_csv(folder / "physical.csv", index=False)
    runs_table().round(6).to_csv(folder / "runs.csv", index=False)


if __name__ == "__main__":
    main()
