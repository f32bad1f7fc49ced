"""Chains that settle in different theta modes: detect and describe them
instead of reporting a blended mean."""

from __future__ import annotations

import logging
import warnings
from dataclasses import dataclass

import numpy as np

logger = logging.getLogger("stancal")


class MultimodalWarning(UserWarning):
    """Chains found separate modes of the theta posterior."""


@dataclass
class Mode:
    chains: list[int]
    theta_mean: dict[str, float]
    theta_q05: dict[str, float]
    theta_q95: dict[str, float]
    mean_log_density: float

    def to_dict(self) -> dict:
        return {
            "chains": self.chains,
            "theta": {k: {"mean": self.theta_mean[k], "q05": self.theta_q05[k],
                          "q95": self.theta_q95[k]} for k in self.theta_mean},
            "mean_log_density": self.mean_log_density,
        }


def _separated(a: np.ndarray, b: np.ndarray, unit_width: np.ndarray) -> bool:
    """Two chains (draw, theta) sit in different modes when, for some theta,
    their central 90 % intervals do not overlap and their means differ by
    more than 3 % of the theta box (tiny gaps are sampling noise)."""
    lo_a, hi_a = np.quantile(a, [0.05, 0.95], axis=0)
    lo_b, hi_b = np.quantile(b, [0.05, 0.95], axis=0)
    apart = (hi_a < lo_b) | (hi_b < lo_a)
    far = np.abs(a.mean(0) - b.mean(0)) > 0.03 * unit_width
    return bool(np.any(apart & far))


def find_modes(theta: np.ndarray, lp: np.ndarray, names: list[str],
               widths: np.ndarray) -> list[Mode]:
    """Group chains into modes. ``theta``: (chain, draw, n_theta) in original
    units; ``lp``: (chain, draw) log density; ``widths``: theta box widths."""
    chains = theta.shape[0]
    parent = list(range(chains))

    def root(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for i in range(chains):
        for j in range(i + 1, chains):
            if not _separated(theta[i], theta[j], widths):
                parent[root(j)] = root(i)
    groups: dict[int, list[int]] = {}
    for c in range(chains):
        groups.setdefault(root(c), []).append(c)
    modes = []
    for members in groups.values():
        pooled = theta[members].reshape(-1, theta.shape[-1])
        modes.append(Mode(
            chains=members,
            theta_mean=dict(zip(names, pooled.mean(0).tolist())),
            theta_q05=dict(zip(names, np.quantile(pooled, 0.05, axis=0).tolist())),
            theta_q95=dict(zip(names, np.quantile(pooled, 0.95, axis=0).tolist())),
            mean_log_density=float(lp[members].mean()),
        ))
    return sorted(modes, key=lambda m: -m.mean_log_density)


def describe(modes: list[Mode]) -> str:
    parts = []
    for k, m in enumerate(modes, start=1):
        theta = ", ".join(f"{n} {m.theta_mean[n]:.4g} [{m.theta_q05[n]:.4g}, {m.theta_q95[n]:.4g}]"
                          for n in m.theta_mean)
        parts.append(f"mode {k} (chains {m.chains}, mean log density {m.mean_log_density:.1f}): {theta}")
    return "; ".join(parts)


def report(modes: list[Mode]) -> None:
    if len(modes) > 1:
        message = (
            f"the chains found {len(modes)} separate theta modes: {describe(modes)}. "
            "Summaries are given per mode (the first has the highest log density); chains "
            "stuck in a mode do not weigh the modes correctly, so compare them, run more "
            "chains, or narrow the theta bounds."
        )
        logger.warning(message)
        warnings.warn(message, MultimodalWarning, stacklevel=3)
