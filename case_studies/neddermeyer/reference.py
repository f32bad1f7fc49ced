"""The near-exact posterior of theta for the Neddermeyer case study
(make_data.py): Neddermeyer's physics evaluated directly on a grid over
theta's box, no emulator, no discrepancy (the data have none), the
measurement error iid N(0, sigma^2) with sigma integrated out under a flat
prior, theta uniform on its box:

    p(theta | y) ∝ SS(theta)^(-(N - 1) / 2),  SS = sum_i (y_i - r(x_i, t_i; theta))^2,

integrated by the midpoint rule on a coarse grid over the whole box, then
on a fine grid around the coarse mode (the posterior is a narrow, tilted
ridge: the fine grid spans +- ``zoom`` of each range). This is the brute-
force quadrature the Kennedy-O'Hagan review recommends as an independent
check of a sampler on a problem of two parameters; against it stancal's
width is measured (docs/neddermeyer.md).

    python case_studies/neddermeyer/reference.py
"""

from __future__ import annotations

import importlib.util
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd


def _physics():
    """make_data.py beside this file, under its own name (another case study's make_data may be loaded)."""
    spec = importlib.util.spec_from_file_location("neddermeyer_make_data", Path(__file__).parent / "make_data.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


make_data = sys.modules.get("neddermeyer_make_data") or _physics()

PRIOR_SD_UNIT = 1 / np.sqrt(12)  # a uniform prior's sd, as a share of its range


@dataclass(frozen=True)
class Reference:
    mean: np.ndarray  # (2,): yield_stress, he_energy, original units
    sd: np.ndarray  # (2,)
    correlation: float
    sd_over_prior: np.ndarray  # sd / (range / sqrt(12))
    edge_mass: float  # posterior mass on the fine grid's border (small: the grid holds the posterior)


def _sum_of_squares(physical: pd.DataFrame, yield_stress: np.ndarray, he_energy: np.ndarray,
                    experiment: str = "shot") -> np.ndarray:
    """SS(theta) at each grid point (same shape as the grids)."""
    total = np.zeros(yield_stress.size)
    for _, rows in physical.groupby(experiment, sort=False):
        times = np.unique(rows["time"].to_numpy())
        radius = make_data.inner_radius(times, rows["mass_ratio"].iloc[0], yield_stress.ravel(), he_energy.ravel())
        at = np.searchsorted(times, rows["time"].to_numpy())
        total += ((rows["radius"].to_numpy() - radius[:, at]) ** 2).sum(axis=1)
    return total.reshape(yield_stress.shape)


def _weights(physical: pd.DataFrame, grids: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, ...]:
    s, u = np.meshgrid(*grids, indexing="ij")
    log_density = -(len(physical) - 1) / 2 * np.log(_sum_of_squares(physical, s, u))
    weight = np.exp(log_density - log_density.max())
    return s, u, weight / weight.sum()


def reference_posterior(physical: pd.DataFrame, coarse: int = 31, fine: int = 61, zoom: float = 0.1) -> Reference:
    """Theta's posterior moments by quadrature (see the module's docstring)."""
    bounds = np.array(list(make_data.THETA_BOUNDS.values()))
    width = bounds[:, 1] - bounds[:, 0]
    s, u, weight = _weights(physical, tuple(np.linspace(lo, hi, coarse) for lo, hi in bounds))
    mode = np.unravel_index(np.argmax(weight), weight.shape)
    centre = np.array([s[mode], u[mode]])
    grids = tuple(np.linspace(max(lo, c - zoom * w), min(hi, c + zoom * w), fine)
                  for (lo, hi), c, w in zip(bounds, centre, width, strict=True))
    s, u, weight = _weights(physical, grids)
    mean = np.array([(weight * s).sum(), (weight * u).sum()])
    ds, du = s - mean[0], u - mean[1]
    cov = np.array([[(weight * ds * ds).sum(), (weight * ds * du).sum()],
                    [(weight * ds * du).sum(), (weight * du * du).sum()]])
    sd = np.sqrt(np.diag(cov))
    edge = weight[0].sum() + weight[-1].sum() + weight[:, 0].sum() + weight[:, -1].sum()
    return Reference(mean, sd, float(cov[0, 1] / (sd[0] * sd[1])), sd / (width * PRIOR_SD_UNIT), float(edge))


if __name__ == "__main__":
    ref = reference_posterior(pd.read_csv(Path(__file__).parent / "physical.csv"))
    for name, m, sd, r in zip(make_data.THETA_BOUNDS, ref.mean, ref.sd, ref.sd_over_prior, strict=True):
        print(f"{name}: mean {m:.4f}, sd {sd:.4f}, sd / prior sd {r:.4f}")
    print(f"correlation {ref.correlation:.3f}; mass on the fine grid's border {ref.edge_mass:.1e}")
