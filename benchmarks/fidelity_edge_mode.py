"""Is the second mode of k at the top of its box real? (docs/multifidelity.md)

The slow coverage study's first seed (tests/test_multifidelity.py's
two-level cooling problem, seed 0, 4 chains of 500 + 1000, seed 1) had a
chain at the top of k's box, R-hat 1.54. This script evaluates modular.stan's
stage-2 log density of that problem in numpy (the co-kriging of
stancal.numerics.multifidelity, noise sd integrated or maximised out):

- along k on the prior's scale, marginal over the noise sd, against the same
  with the exact expensive simulator in place of the emulator;
- on the sampler's scale, (logit theta, log noise sd) with their Jacobians,
  for local maxima;
- the emulator's predictive sd at the physical points along k.

With --fit it also runs the fit (4 chains, 500 + 1000, seed 1) and prints the
chains' k, stancal's modes and their weights (stancal.numerics.mode_mass).

    python benchmarks/fidelity_edge_mode.py [--problem-seed 0] [--stage-one-seed 1] [--fit]

(calibrate's stage 1 takes the sampler's seed: --stage-one-seed 1 for the fit with seed 1.)
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from scipy import stats
from scipy.ndimage import maximum_filter
from scipy.special import expit

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

import test_multifidelity as two_level  # noqa: E402

from stancal.fitting.stage_one import fidelity_levels, fit_fidelity_emulator  # noqa: E402
from stancal.numerics import multifidelity as mf  # noqa: E402


def log_density(levels, x, y, theta_unit: float, noise: np.ndarray) -> np.ndarray:
    """modular.stan's log density (no discrepancy) at one theta, for each noise sd: standardised units."""
    mean, cov = mf.predictive(levels, np.hstack([x, np.full((len(x), 1), theta_unit)]))
    values, vectors = np.linalg.eigh(cov)
    projected = vectors.T @ (y - mean)
    variance = np.maximum(values, 0)[:, None] + noise[None, :] ** 2
    return (-0.5 * (projected[:, None] ** 2 / variance).sum(0) - 0.5 * np.log(variance).sum(0)
            + stats.halfnorm.logpdf(noise))


def exact_log_density(data, y, k: float, noise: np.ndarray) -> np.ndarray:
    """The same with the exact expensive simulator in place of the emulator."""
    f = data.scaling.standardise(two_level.radiating(data.physical["t"].to_numpy(), k))
    return -0.5 * ((y - f) ** 2).sum() / noise**2 - len(y) * np.log(noise) + stats.halfnorm.logpdf(noise)


def along_k(data, levels, x, y) -> None:
    theta = np.linspace(0, 1, 301)
    k = two_level.K_BOUNDS[0] + np.ptp(two_level.K_BOUNDS) * theta
    noise = np.linspace(0.001, 0.3, 600)
    marginal = np.array([np.logaddexp.reduce(log_density(levels, x, y, t, noise)) for t in theta])
    exact = np.array([np.logaddexp.reduce(exact_log_density(data, y, kk, noise)) for kk in k])
    sd = [np.sqrt(np.diag(mf.predictive(levels, np.hstack([x, np.full((len(x), 1), t)]))[1]).mean()) for t in theta]
    marginal, exact = marginal - marginal.max(), exact - exact.max()
    peaks = [i for i in range(1, len(k)) if marginal[i] >= marginal[i - 1]
             and (i == len(k) - 1 or marginal[i] >= marginal[i + 1])]
    print("log p(k | y), noise sd integrated out, prior's scale; local maxima:",
          [(round(float(k[i]), 3), round(float(marginal[i]), 2)) for i in peaks])
    if len(peaks) > 1:
        trough = peaks[0] + int(np.argmin(marginal[peaks[0]:peaks[-1] + 1]))
        weights = np.exp(marginal) / np.exp(marginal).sum()
        exact_weights = np.exp(exact) / np.exp(exact).sum()
        print(f"  trough at k = {k[trough]:.3f} ({marginal[trough]:.2f}); mass above it: {weights[trough:].sum():.2g} "
              f"(exact simulator: {exact_weights[trough:].sum():.2g})")
    print("| k | log p, emulator | log p, exact simulator | emulator sd at the points (standardised) |")
    print("|---|---|---|---|")
    for value in (1.2, 1.4, 1.6, 1.8, 1.9, 1.95, 2.0):
        i = int(np.argmin(abs(k - value)))
        print(f"| {value:.2f} | {marginal[i]:.2f} | {exact[i]:.2f} | {sd[i]:.3f} |")


def sampler_scale(data, levels, x, y) -> None:
    """Local maxima of the log density on (logit theta, log noise sd), Jacobians included."""
    u = np.linspace(-4, 16, 401)
    v = np.linspace(np.log(1e-3), np.log(3.0), 500)
    theta = expit(u)
    grid = np.array([log_density(levels, x, y, t, np.exp(v)) + v + np.log(t) + np.log1p(-t) for t in theta])
    grid -= grid.max()
    maxima = np.argwhere(grid == maximum_filter(grid, size=5, mode="nearest"))
    k = two_level.K_BOUNDS[0] + np.ptp(two_level.K_BOUNDS) * theta
    print("sampler's scale (logit theta, log noise sd): local maxima",
          [(round(float(k[i]), 4), round(float(u[i]), 2), round(float(grid[i, j]), 2)) for i, j in maxima])
    for value in (2, 4, 8, 12):
        i = int(np.argmin(abs(u - value)))
        print(f"  logit theta = {value}: k = {k[i]:.5f}, highest log density {grid[i].max():.2f} "
              f"at noise sd {np.exp(v[grid[i].argmax()]) * data.scaling.y_scale:.3f} (original units)")


def fit_and_modes(problem_seed: int, seed: int) -> None:
    from conftest import fit

    result = fit(two_level.problem(seed=problem_seed), method="modular", discrepancy="none", chains=4, warmup=500,
                 draws=1000, seed=seed)
    theta = np.asarray(result.idata["posterior"]["theta"])[..., 0]
    print("chains' k: mean", theta.mean(axis=1).round(4), "min", theta.min(axis=1).round(4),
          "max", theta.max(axis=1).round(4))
    print(f"max R-hat {result.diagnostics.max_rhat:.3f}; divergences {result.diagnostics.divergences}")
    for m in result.modes:
        print("mode", m.to_dict())


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--problem-seed", type=int, default=0)
    parser.add_argument("--stage-one-seed", type=int, default=1)
    parser.add_argument("--fit", action="store_true")
    args = parser.parse_args()
    data = two_level.problem(seed=args.problem_seed)
    x = data.scaling.to_unit(data.physical, data.inputs)
    y = data.scaling.standardise(data.physical[data.output].to_numpy())
    stage_one = fit_fidelity_emulator(data, seed=args.stage_one_seed)
    levels = fidelity_levels(data, stage_one["hyperparameters"]["levels"])
    print(f"expensive runs' k: {np.sort(data.runs['k'].to_numpy()).round(3)}; top level's variance factor "
          f"{stage_one['top_level_variance_factor']:.3g}")
    along_k(data, levels, x, y)
    sampler_scale(data, levels, x, y)
    if args.fit:
        fit_and_modes(args.problem_seed, args.stage_one_seed)


if __name__ == "__main__":
    main()
