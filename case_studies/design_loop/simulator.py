"""The simulator of the design-loop case study: the steady temperature along
a pin fin (Incropera et al., Fundamentals of Heat and Mass Transfer, 7th
ed., section 3.6.2, the fin with a convective tip), standing in for an
expensive code whose runs are counted.

T(x) = T_a + eta (T_b - T_a) [cosh m(L - x) + (h / m k) sinh m(L - x)] /
       [cosh mL + (h / m k) sinh mL],   m = sqrt(4 h / (k d)),

for a pin of diameter d and length L with its base at T_b behind a contact
of efficiency eta. Five parameters: the convection coefficient h, the
conductivity k, the ambient temperature T_a, the contact efficiency eta, and
the specific heat c_p, which a steady state does not depend on (the
inactive one). h and k enter only through h / k: a ridge that history
matching has to find and calibration cannot cut.

The "real" fin (``measured``) also loses heat by radiation, eps sigma (T^4 -
T_a^4) per unit area with eps = 0.1 (polished aluminium), which the
simulator leaves out: its discrepancy, largest at the hot base.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
from scipy import linalg

DIAMETER, LENGTH = 0.01, 0.3  # m
THETA = {"h": (5.0, 60.0), "k": (50.0, 400.0), "T_a": (15.0, 30.0), "eta": (0.8, 1.0), "c_p": (400.0, 1200.0)}
TRUTH = {"h": 20.0, "k": 180.0, "T_a": 22.0, "eta": 0.93, "c_p": 900.0}
EMISSIVITY, STEFAN_BOLTZMANN = 0.1, 5.670e-8


def fin_temperature(frame: pd.DataFrame) -> np.ndarray:
    """The simulator at each row of ``frame`` (columns x, T_b and the theta): deg C."""
    x, T_b = frame["x"].to_numpy(float), frame["T_b"].to_numpy(float)
    h, k, T_a, eta = (frame[name].to_numpy(float) for name in ("h", "k", "T_a", "eta"))
    m = np.sqrt(4 * h / (k * DIAMETER))
    tip = h / (m * k)
    shape = (np.cosh(m * (LENGTH - x)) + tip * np.sinh(m * (LENGTH - x))) / (np.cosh(m * LENGTH)
                                                                             + tip * np.sinh(m * LENGTH))
    return T_a + eta * (T_b - T_a) * shape


def measured(x: np.ndarray, T_b: float, nodes: int = 400) -> np.ndarray:
    """The real fin at the truth: convection and radiation, by finite
    differences with Newton's method (deg C at the positions x)."""
    h, k, T_a, eta = (TRUTH[name] for name in ("h", "k", "T_a", "eta"))
    grid = np.linspace(0, LENGTH, nodes)
    step = grid[1]
    base = T_a + eta * (T_b - T_a)
    T = np.full(nodes, base)
    kelvin = 273.15
    for _ in range(50):
        radiation = EMISSIVITY * STEFAN_BOLTZMANN * ((T + kelvin) ** 4 - (T_a + kelvin) ** 4)
        d_radiation = 4 * EMISSIVITY * STEFAN_BOLTZMANN * (T + kelvin) ** 3
        loss = 4 / DIAMETER * (h * (T - T_a) + radiation)  # per unit volume, over k
        residual = np.empty(nodes)
        residual[0] = T[0] - base
        residual[1:-1] = k * (T[2:] - 2 * T[1:-1] + T[:-2]) / step**2 - loss[1:-1]
        # the tip: conduction out equals convection and radiation from the tip face (half a cell's losses too)
        residual[-1] = (-k * (T[-1] - T[-2]) / step - (h * (T[-1] - T_a) + radiation[-1])
                        - step / 2 * loss[-1])
        bands = np.zeros((3, nodes))
        bands[1, 0] = 1
        bands[0, 2:] = k / step**2
        bands[1, 1:-1] = -2 * k / step**2 - 4 / DIAMETER * (h + d_radiation[1:-1])
        bands[2, :-2] = k / step**2
        bands[1, -1] = -k / step - (h + d_radiation[-1]) - step / 2 * 4 / DIAMETER * (h + d_radiation[-1])
        bands[2, -2] = k / step
        change = linalg.solve_banded((1, 1), bands, -residual)
        T += change
        if np.abs(change).max() < 1e-10:
            break
    return np.interp(x, grid, T)
