"""The Tuo & Wu (2015) toy problem of the review's section 6.2: data, the
L2 projection theta* by quadrature, and the problem as a CalibrationData."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
from scipy import integrate, optimize

SIMULATOR = Path(__file__).with_name("simulator.stan")


def zeta(x):
    return np.exp(x / 10) * np.sin(x)


def simulator(x, theta):
    return zeta(x) - np.sqrt(theta**2 - theta + 1) * (np.sin(theta * x) + np.cos(theta * x))


def l2_loss(theta: float) -> float:
    """||zeta - f(., theta)||^2 over (0, 2 pi), by adaptive quadrature."""
    value, _ = integrate.quad(lambda x: (zeta(x) - simulator(x, theta)) ** 2, 0, 2 * np.pi, limit=200)
    return value


def l2_projection() -> float:
    """theta* = argmin of the L2 loss over (-2, 2): grid first (the loss is
    multimodal), then a bounded refinement around the best grid point."""
    grid = np.linspace(-2, 2, 401)
    best = grid[np.argmin([l2_loss(t) for t in grid])]
    res = optimize.minimize_scalar(l2_loss, bounds=(best - 0.01, best + 0.01), method="bounded",
                                   options={"xatol": 1e-8})
    return float(res.x)


def physical_data(seed: int) -> pd.DataFrame:
    """x_i = 2 pi i / 30, i = 0..30, y = zeta(x) + N(0, 1)."""
    x = 2 * np.pi * np.arange(31) / 30
    return pd.DataFrame({"x": x, "y": zeta(x) + np.random.default_rng(seed).standard_normal(31)})


def problem(seed: int):
    import stancal

    return stancal.CalibrationData(physical_data(seed), ["x"], "y", {"theta": (-2.0, 2.0)})
