"""Why modular_heteroscedastic's SBC rejects its noise sd: the fits, or the data they are ranked on?

Simulation-based calibration (SBC; Talts, Betancourt, Simpson, Vehtari &
Gelman 2018, "Validating Bayesian inference algorithms with simulation-based
calibration", arXiv:1804.06788) rejects the family's noise sd. `ranks` sets
each simulation's fit rank beside an exact reference rank and the simulated
scatter's own statistic Q; `generator` tests the simulated data themselves.

    nice -n 19 env OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/sbc_heteroscedastic_check.py \\
        ranks FITS_DIR [--out JSON] [--toy 10000]
    ... paired SHORT_FITS LONG_FITS [--out JSON]
    ... generator [--draws 4000] [--seed 2] [--out JSON] [--fits FITS_DIR]
    ... generator --reanalyse NPZ [--out JSON]
    ... written RANKS_JSONL [--seed 2] [--out JSON]

`ranks` reads a finished SBC run of the family, FITS_DIR being the folder
`benchmarks/sbc_families.py --out OUT` writes (OUT/modular_heteroscedastic/fits;
only simulations with finished.json are read); it fits and compiles nothing.
`generator` runs the family's prior once, long (minutes), and tests every draw's
simulated data against that draw's own parameters; with --fits it matches SBC's
truths to the run's draws. `--reanalyse NPZ` reruns only its jitter check on the
draws a run saved (JSON with .npz), adding it to JSON. `paired` sets each
simulation's ranks from two runs on the same simulated data side by side (the
default short fits and longer ones, `sbc_families.py --subset N --warmup W
--draws D`): if the longer fits' noise-sd ranks are lower by more than two
standard errors, the short fits were the cause; else the model. `written` sets
the ranks of benchmarks/sbc_written_out.py's simulations (truths and data drawn
by numpy, each again from its seed) beside the same exact reference, as `ranks`
does for Stan's. All print and write JSON.

The model (stan_models/modular.stan, functions/noise.stan, docs/noise.md)
-------------------------------------------------------------------------
Standardised output y* = (y - y_center) / y_scale (the design's scaling, kept by
every SBC fit). Noise inputs u = t, 10 distinct values (locations k) on the unit
scale. With sigma = noise_sd (standardised), K the SE covariance (sd a, length
scale l) and z ~ N(0, I),

    g = chol(K + 1e-6 a^2 I) z,    s_i = sigma exp(g[loc_i] - mean_k g_k),

so sigma is the geometric mean of the sd over the locations. Priors: sigma ~
half-normal(0, 1), a ~ half-normal(0, 1), l ~ lognormal(noise_length_scale_prior),
all independent. Everything else (emulator variance, nugget, discrepancy) is
common to the 4 replicates of one (t, T0) setting, so their deviations from the
setting mean involve the noise alone.

Q statistic
-----------
With r_k = exp(g_k - mean g) the true shape and setting j of 4 rows,
W = sum_j sum_{i in j} (y*_i - mean_j y*)^2 / r_{loc(j)}^2 and Q = W / sigma^2 ~
chi^2(20 x 3 = 60) given sigma and the shape, whatever the setting means.

Exact reference posterior
-------------------------
Condition on W alone, the shape known and only the scale sigma unknown: W | sigma
= sigma^2 chi^2_60, and the prior half-normal(0, 1) on sigma is independent of the
(centred) shape, so

    p(sigma | W) propto exp(-sigma^2 / 2) sigma^-60 exp(-W / (2 sigma^2)).

It is a proper posterior of the statistic W, so for sigma from the prior and W
simulated given it, F(sigma_true | W) is exactly U(0, 1): the rank a perfect fit
using W alone would give. In v = log sigma (the Jacobian adds one power of sigma)
log p(v) = -e^{2v}/2 - 59 v - W e^{-2v}/2, concave, mode at
e^{2v} = (-59 + sqrt(59^2 + 4W)) / 2; the CDF is the trapezoid rule on 4001
points over the mode +- 20 curvature sds. The toy checks it against
scipy.integrate.quad and its uniformity on simulations from the prior through
the same code as the real data.

Fit ranks
---------
rank = #(ranked draws < truth), checked against finished.json's "kept" (what
sbc.py computed). The tenths use sbc.py's fractional ranks (one generator
seeded with the SBC's seed, parameter after parameter), so the gamma p-value is
the one sbc.py reports once every simulation has finished.

Generator
---------
One prior run as simulation_based_calibration makes SBC's (the family's design
and options from sbc_families.py, warm-up 300, the discrepancy non-centred,
chains=1), only with --draws draws. Given a draw, y_rep = normal_rng(zeta, s)
with zeta common to a setting's replicates, so its Q ~ chi2(60) exactly and each
setting's term ~ chi2(3), with fresh noise in every draw. The locations, rows'
locations and scaling are the Stan data the program was given, checked against
the design `ranks` uses. With the same seed a longer run repeats a shorter one's
draws first, so SBC's truths are found among the draws, and their Q compared
with `ranks`' Q of the same simulations.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import numpy as np
import xarray as xr
from scipy import integrate, stats

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import sbc_families  # noqa: E402  (the family's design and options, as its SBC ran them)

import stancal  # noqa: E402
from stancal.diagnosing.moment_match import fit_stan_data  # noqa: E402
from stancal.diagnosing.sbc import functional_parametrizations  # noqa: E402
from stancal.diagnosing.sbc_ranks import fractional_ranks, rank_of, uniformity  # noqa: E402
from stancal.fitting.calibrate import calibrate  # noqa: E402
from stancal.fitting.plan import model_keywords  # noqa: E402
from stancal.fitting.resume import write_json  # noqa: E402
from stancal.numerics.kernels import ard_cross_cov  # noqa: E402
from stancal.numerics.scalable_emulator import JITTER  # noqa: E402
from stancal.problem.codes import Kernel  # noqa: E402
from stancal.problem.noise import NoiseLocations  # noqa: E402
from stancal.problem.run_replicates import group_settings  # noqa: E402

FAMILY = "modular_heteroscedastic"
NOISE = "noise_sd"  # the parameter SBC rejects (noise_sd_original: sigma x y_scale)
GRID_POINTS, GRID_HALF_WIDTH = 4001, 20.0  # the reference's grid in log sigma: points, curvature sds each side
TOY_SEED = 12345
PRIOR_WARMUP = 300  # sbc_families.py's default --warmup, which SBC's prior run took too
SIMULATIONS = 200  # sbc_families.py's default --sims: SBC's prior run thinned to this many draws
TINY_SD = 0.003  # a location sd (standardised) this small lets the generator's jitter dominate its scatter


# ---------------------------------------------------------------- the design
def settings_of(t: np.ndarray, t0: np.ndarray) -> np.ndarray:
    """Each row's (t, T0) setting: the package's one exact grouping (run_replicates.group_settings)."""
    return group_settings(np.column_stack([t, t0]))[1]


def dof_of(setting: np.ndarray) -> int:
    """The scatter's degrees of freedom: one per replicate beyond the first of each setting."""
    return int(sum(np.sum(setting == j) - 1 for j in np.unique(setting)))


@dataclass(frozen=True)
class Design:
    """The hetero_noise design as the family's SBC saw it: scaling, settings and noise locations."""

    data: stancal.CalibrationData
    locations: NoiseLocations
    setting: np.ndarray

    @classmethod
    def load(cls) -> Design:
        data = sbc_families.hetero_design()
        locations = NoiseLocations.of(data.scaling.to_unit(data.physical, ["t"]), ["t"])
        return cls(data, locations, settings_of(data.physical["t"].to_numpy(float),
                                                data.physical["T0"].to_numpy(float)))

    @property
    def unit_t(self) -> np.ndarray:
        return self.locations.unit[:, 0]

    @property
    def location(self) -> np.ndarray:
        return self.locations.row_location

    @property
    def dof(self) -> int:
        return dof_of(self.setting)


def log_sd_shape(unit_t: np.ndarray, gp_sd: float, length_scale: float, z: np.ndarray) -> np.ndarray:
    """g - mean(g) at the locations (noise_log_scale_at, centred as row_noise_variance does), with
    the kernel and jitter numerics.noise_gp uses."""
    points = unit_t[:, None]
    k = ard_cross_cov(points, points, Kernel.SE, gp_sd, [length_scale]) + JITTER * gp_sd**2 * np.eye(len(unit_t))
    g = np.linalg.cholesky(k) @ z
    return g - g.mean()


def setting_squares(y_std: np.ndarray, setting: np.ndarray) -> np.ndarray:
    """(draws, settings): each setting's squared deviations of its replicates from their mean, summed."""
    out = np.empty((len(y_std), setting.max() + 1))
    for j in range(out.shape[1]):
        rows = y_std[:, setting == j]
        out[:, j] = np.sum((rows - rows.mean(axis=1, keepdims=True)) ** 2, axis=1)
    return out


def setting_locations(setting: np.ndarray, location: np.ndarray) -> np.ndarray:
    """Each setting's noise location (.item() fails if a setting spanned two)."""
    return np.array([np.unique(location[setting == j]).item() for j in range(setting.max() + 1)])


def scatter_w(y_std: np.ndarray, setting: np.ndarray, location: np.ndarray, shape: np.ndarray) -> float:
    """W: replicates' squared deviations from their setting mean over the true squared shape (standardised)."""
    squares = setting_squares(y_std[None, :], setting)[0]
    return float(np.sum(squares / np.exp(2 * shape[setting_locations(setting, location)])))


def true_scatter(y: np.ndarray, par: dict, design: Design) -> tuple[float, np.ndarray]:
    """W of simulated y (original units) given the truth's Stan parameters, and the true shape."""
    shape = log_sd_shape(design.unit_t, par["noise_gp_sd"][0], par["noise_length_scale"][0],
                         np.asarray(par["noise_z"]))
    return scatter_w(design.data.scaling.standardise(y), design.setting, design.location, shape), shape


# ------------------------------------------------------- the exact reference
def reference_cdf(w: np.ndarray, sigma: np.ndarray, dof: int) -> np.ndarray:
    """F(sigma | W) under p(sigma | W) propto HN(sigma; 0, 1) sigma^-dof exp(-W / 2 sigma^2), vectorised."""
    w, sigma = np.atleast_1d(np.asarray(w, float)), np.atleast_1d(np.asarray(sigma, float))
    power = dof - 1  # sigma^-dof times the Jacobian sigma of v = log sigma
    mode_v = 0.5 * np.log((-power + np.sqrt(power**2 + 4 * w)) / 2)
    curvature = 2 * np.exp(2 * mode_v) + 2 * w * np.exp(-2 * mode_v)
    sd_v = 1 / np.sqrt(curvature)
    steps = np.linspace(-GRID_HALF_WIDTH, GRID_HALF_WIDTH, GRID_POINTS)
    v = mode_v[:, None] + sd_v[:, None] * steps[None, :]
    logp = -0.5 * np.exp(2 * v) - power * v - 0.5 * w[:, None] * np.exp(-2 * v)
    p = np.exp(logp - logp.max(axis=1, keepdims=True))
    dv = np.diff(v, axis=1)
    cum = np.concatenate([np.zeros((len(w), 1)), np.cumsum(0.5 * (p[:, 1:] + p[:, :-1]) * dv, axis=1)], axis=1)
    cum /= cum[:, -1:]
    return np.array([np.interp(np.log(s), vi, ci, left=0.0, right=1.0)
                     for s, vi, ci in zip(sigma, v, cum, strict=True)])


def reference_cdf_quad(w: float, sigma: float, dof: int) -> float:
    """The same by scipy.integrate.quad on sigma: the check of the grid."""
    mode = np.sqrt((-(dof - 1) + np.sqrt((dof - 1) ** 2 + 4 * w)) / 2)

    def log_density(s):
        return -0.5 * s**2 - dof * np.log(s) - 0.5 * w / s**2

    top = log_density(mode)

    def density(s):
        return np.exp(log_density(s) - top)

    below = integrate.quad(density, 0, sigma, points=[mode] if mode < sigma else None, limit=200)[0]
    total = integrate.quad(density, 0, mode, limit=200)[0] + integrate.quad(density, mode, np.inf, limit=200)[0]
    return below / total


# ----------------------------------------------------------------- statistics
def tenths(u: np.ndarray) -> list[int]:
    return np.bincount(np.minimum((np.asarray(u) * 10).astype(int), 9), minlength=10).tolist()


def chi2_uniform(u: np.ndarray) -> float:
    return float(stats.chisquare(tenths(u)).pvalue)


def lag1(x: np.ndarray) -> float:
    x = np.asarray(x, float) - np.mean(x)
    return float(np.sum(x[1:] * x[:-1]) / np.sum(x * x))


def summary(stat: np.ndarray, dof: int) -> dict:
    """How far a statistic meant to be chi2(dof) is from it: its CDF's uniformity, lowest tenth, moments."""
    u = stats.chi2.cdf(stat, dof)
    n = len(u)
    low = int(np.sum(u < 0.1))
    return {"n": n, "dof": dof, "ks_p": float(stats.kstest(u, "uniform").pvalue), "tenths": tenths(u),
            "lowest_tenth": low, "lowest_tenth_frac": low / n,
            "lowest_tenth_binom_p_two_sided": float(stats.binomtest(low, n, 0.1).pvalue),
            "lowest_tenth_binom_p_upper": float(stats.binom.sf(low - 1, n, 0.1)),
            "mean_over_dof": float(np.mean(stat) / dof), "mean_over_dof_se": float(np.sqrt(2 / dof / n)),
            "mean_over_dof_se_empirical": float(np.std(stat, ddof=1) / dof / np.sqrt(n)),
            "var_over_2dof": float(np.var(stat, ddof=1) / (2 * dof)),
            "lag1_autocorr_cdf": lag1(u), "lag1_autocorr_stat": lag1(stat)}


# -------------------------------------------------------------------- ranks
def toy(n: int, seed: int, design: Design) -> dict:
    """Scatter simulated from the prior (sigma, a, l, z) on the design's settings, through the same W
    and reference code as the real data: are the reference's ranks uniform?"""
    rng = np.random.default_rng(seed)
    unit_t, setting, location, dof = design.unit_t, design.setting, design.location, design.dof
    ls_prior = design.locations.length_scale_prior()
    sigma = np.abs(rng.standard_normal(n))
    w = np.empty(n)
    for i in range(n):
        shape = log_sd_shape(unit_t, abs(rng.standard_normal()), rng.lognormal(*ls_prior),
                             rng.standard_normal(len(unit_t)))
        means = rng.normal(0, 3, setting.max() + 1)[setting]  # any setting means: W ignores them
        y = means + sigma[i] * np.exp(shape[location]) * rng.standard_normal(len(setting))
        w[i] = scatter_w(y, setting, location, shape)
    u = reference_cdf(w, sigma, dof)
    q_cdf = stats.chi2.cdf(w / sigma**2, dof)
    quad_idx = rng.choice(n, 20, replace=False)
    quad = np.array([reference_cdf_quad(w[i], sigma[i], dof) for i in quad_idx])
    return {"simulations": n, "seed": seed, "dof": dof, "reference_tenths": tenths(u),
            "reference_chi2_p": chi2_uniform(u), "reference_ks_p": float(stats.kstest(u, "uniform").pvalue),
            "reference_mean": float(u.mean()), "q_cdf_ks_p": float(stats.kstest(q_cdf, "uniform").pvalue),
            "grid_vs_quad_max_abs_diff": float(np.max(np.abs(u[quad_idx] - quad)))}


def simulated_data(folder: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A simulation's data as its fit saw them: y (original units) and each row's t and T0."""
    with xr.open_datatree(folder / "posterior.nc") as tree:
        return (tree["observed_data"]["y"].values.astype(float), tree["constant_data"]["t"].values.astype(float),
                tree["constant_data"]["T0"].values.astype(float))


class Simulation(NamedTuple):
    """One finished simulation as `ranks` reads it."""

    record: dict  # its line in the report
    kept: dict[str, int]  # sbc.py's ranks (finished.json)
    draws_per_fit: int  # L, the draws each truth was ranked among
    mismatches: list[str]  # ranks recomputed here that differ from sbc.py's
    issues: list[str]  # anything else amiss


def simulation(folder: Path, design: Design) -> Simulation:
    """One finished simulation: its truths' ranks recomputed, its data checked, its Q and reference rank."""
    truth = json.loads((folder / "truth.json").read_text())
    ranked = json.loads((folder / "ranked_draws.json").read_text())
    kept = json.loads((folder / "finished.json").read_text())["kept"]
    kept = kept.get("ranks", kept)  # since 2026-11-29 the ranks beside the fit's health
    values, par, draws_per_fit = truth["values"], truth["stan_parameters"], len(ranked[NOISE])
    ranks = {name: rank_of(values[name], np.asarray(d)) for name, d in ranked.items()}
    mismatches = [f"{folder.name}: {name} rank {r} != sbc.py's {kept.get(name)}"
                  for name, r in ranks.items() if kept.get(name) != r]
    issues = []
    y, t, t0 = simulated_data(folder)
    physical, scaling = design.data.physical, design.data.scaling
    if not (np.allclose(t, physical["t"].to_numpy(float)) and np.allclose(t0, physical["T0"].to_numpy(float))):
        raise SystemExit(f"{folder}: the rows' (t, T0) differ from the design's")
    if np.allclose(y, physical[design.data.output].to_numpy(float)):
        issues.append(f"{folder.name}: observed_data is the case study's own data, not a simulation")
    sigma_std = float(par["noise_sd"][0])
    # the reported values are the Stan parameters in original units: the scaling must match the design's
    checks = (values[NOISE] / sigma_std / scaling.y_scale - 1,
              values["noise_length_scale[t]"] / par["noise_length_scale"][0] / scaling.width["t"] - 1)
    if max(abs(c) for c in checks) > 1e-9:
        issues.append(f"{folder.name}: scaling mismatch {checks}")
    w, shape = true_scatter(y, par, design)
    q = w / sigma_std**2
    record = {"simulation": int(folder.name), "noise_sd_true": values[NOISE], "sigma_std_true": sigma_std,
              "rank": ranks[NOISE], "rank_norm": ranks[NOISE] / draws_per_fit, "Q": q,
              "Q_cdf": float(stats.chi2.cdf(q, design.dof)), "W": w,
              "reference_rank": float(reference_cdf(w, sigma_std, design.dof)[0]),
              "geometric_mean_check": float(np.exp(np.mean(np.log(sigma_std * np.exp(shape)))) / sigma_std),
              "ranks_all": {k: v / draws_per_fit for k, v in ranks.items()}}
    return Simulation(record, kept, draws_per_fit, mismatches, issues)


def per_parameter(kept_all: dict[str, list[int]], draws_per_fit: int, seed: int) -> dict[str, dict]:
    """Each parameter's tests on sbc.py's fractional ranks: one generator, parameter after parameter."""
    rng = np.random.default_rng(seed)
    out = {}
    for name, kept in kept_all.items():
        frac = fractional_ranks(kept, draws_per_fit, rng)
        out[name] = {"gamma_p": uniformity(frac, 0.95, seed).p_value, "tenths": tenths(frac),
                     "chi2_p": chi2_uniform(frac), "mean_rank_norm": float(np.mean(kept) / draws_per_fit)}
    return out


def ranks_summary(sims: list[dict], seed: int, dof: int) -> dict:
    """The noise sd's fit ranks, Q and the reference over the simulations, and fit against reference."""
    n = len(sims)
    rank_norm, q, q_cdf, ref = (np.array([s[key] for s in sims])
                                for key in ("rank_norm", "Q", "Q_cdf", "reference_rank"))
    diff = rank_norm - ref
    return {
        "Q": {"dof": dof, "ks_p_chi2": float(stats.kstest(q_cdf, "uniform").pvalue), "tenths": tenths(q_cdf),
              "mean_Q_over_dof": float(q.mean() / dof), "mean_Q_over_dof_se": float(np.sqrt(2 / dof / n)),
              "lowest_tenth": int(np.sum(q_cdf < 0.1)), "lowest_tenth_expected": n / 10,
              "lowest_tenth_binom_p_upper": float(stats.binom.sf(np.sum(q_cdf < 0.1) - 1, n, 0.1)),
              "spearman_rank_vs_Q": float(stats.spearmanr(rank_norm, q).statistic),
              "spearman_reference_vs_Q": float(stats.spearmanr(ref, q).statistic)},
        "reference": {"tenths": tenths(ref), "chi2_p": chi2_uniform(ref),
                      "ks_p": float(stats.kstest(ref, "uniform").pvalue),
                      "gamma_p": uniformity(ref, 0.95, seed).p_value, "mean": float(ref.mean()),
                      "spearman_fit_vs_reference": float(stats.spearmanr(rank_norm, ref).statistic)},
        "paired": {"mean_fit_minus_reference": float(diff.mean()), "sd": float(diff.std(ddof=1)),
                   "t_test_p": float(stats.ttest_1samp(diff, 0).pvalue),
                   "wilcoxon_p": float(stats.wilcoxon(diff).pvalue),
                   "fit_above_reference": int(np.sum(diff > 0))}}


def print_toy(t: dict) -> None:
    print(f"toy ({t['simulations']} sims from the prior, same code path): reference tenths "
          f"{t['reference_tenths']}, chi2 p = {t['reference_chi2_p']:.3f}, KS p = {t['reference_ks_p']:.3f}, "
          f"mean {t['reference_mean']:.4f}; Q cdf KS p = {t['q_cdf_ks_p']:.3f}; grid vs quad max "
          f"|diff| {t['grid_vs_quad_max_abs_diff']:.1e}")


def print_ranks(report: dict) -> None:
    f, qq, r, p = report["noise_sd_fit"], report["Q"], report["reference"], report["paired"]
    n, dof = report["finished_simulations"], qq["dof"]
    print(f"{n} finished simulations in {report['fits']} (L = {report['draws_per_fit']}, sbc seed "
          f"{report['sbc_seed']})")
    print(f"ranks recomputed from ranked_draws.json vs finished.json: {report['rank_mismatch_count']} mismatches "
          f"over {len(report['all_parameters'])} parameters")
    print(f"noise_sd fit: tenths {f['tenths']}  chi2 p = {f['chi2_p']:.3f}  sbc gamma p = {f['gamma_p']:.3f}  "
          f"mean rank/L {f['mean_rank_norm']:.3f}")
    print(f"Q ~ chi2({dof}): mean Q/dof {qq['mean_Q_over_dof']:.3f} (se {qq['mean_Q_over_dof_se']:.3f}); "
          f"KS p = {qq['ks_p_chi2']:.3f}; tenths {qq['tenths']}; lowest tenth "
          f"{qq['lowest_tenth']} (expected {n / 10:.1f}, binomial upper p = {qq['lowest_tenth_binom_p_upper']:.3f}); "
          f"Spearman(rank, Q) = {qq['spearman_rank_vs_Q']:.2f} (reference vs Q {qq['spearman_reference_vs_Q']:.2f})")
    print(f"reference: tenths {r['tenths']}  chi2 p = {r['chi2_p']:.3f}  KS p = {r['ks_p']:.3f}  gamma p = "
          f"{r['gamma_p']:.3f}  mean {r['mean']:.3f}; Spearman(fit, reference) = {r['spearman_fit_vs_reference']:.2f}")
    print(f"paired fit rank/L - reference: mean {p['mean_fit_minus_reference']:+.4f} (sd {p['sd']:.3f}), t-test p = "
          f"{p['t_test_p']:.4f}, Wilcoxon p = {p['wilcoxon_p']:.4f}, fit above in {p['fit_above_reference']} of {n}")
    print("all parameters (sbc-style fractional ranks): " + "; ".join(
        f"{k} gamma p {v['gamma_p']:.2f} chi2 p {v['chi2_p']:.2f}" for k, v in report["all_parameters"].items()))
    if report["other_issues"]:
        print("issues:", *report["other_issues"][:10], sep="\n  ")


def ranks(args: argparse.Namespace) -> None:
    design = Design.load()
    scaling = design.data.scaling
    seed_file = args.fits_dir.parent / "seed.json"  # the SBC's seed: its fractional ranks' generator
    seed = json.loads(seed_file.read_text())["seed"] if seed_file.is_file() else 1
    report: dict = {"fits": str(args.fits_dir), "design": {
        "rows": len(design.setting), "settings": int(design.setting.max() + 1),
        "noise_locations": len(design.unit_t), "dof": design.dof, "y_scale": scaling.y_scale,
        "t_width": scaling.width["t"], "length_scale_prior": list(design.locations.length_scale_prior())}}
    if args.toy:
        report["toy"] = toy(args.toy, TOY_SEED, design)
        print_toy(report["toy"])
    sims, mismatches, issues, kept_all = [], [], [], {}
    for folder in sorted(p for p in args.fits_dir.iterdir() if (p / "finished.json").is_file()):
        one = simulation(folder, design)
        sims.append(one.record)
        mismatches += one.mismatches
        issues += one.issues
        for name, rank in one.kept.items():
            kept_all.setdefault(name, []).append(rank)
    draws_per_fit = one.draws_per_fit  # every fit ranks among the same number of draws
    parameters = per_parameter(kept_all, draws_per_fit, seed)
    report.update({"finished_simulations": len(sims), "draws_per_fit": draws_per_fit, "sbc_seed": seed,
                   "rank_mismatches_vs_sbc": mismatches[:20], "rank_mismatch_count": len(mismatches),
                   "noise_sd_fit": parameters[NOISE], **ranks_summary(sims, seed, design.dof),
                   "all_parameters": parameters, "other_issues": issues, "simulations": sims})
    print_ranks(report)
    write_json(args.out, report)
    print(f"written {args.out}")


# ----------------------------------------------------------------- generator
def prior_run(draws: int, seed: int):
    """calibrate(..., prior=True, chains=1) as simulation_based_calibration calls it for the family."""
    design_name, options = sbc_families.FAMILIES[FAMILY]
    data = sbc_families.DESIGNS[design_name]()
    calibrate_options = dict(options)
    simulator = calibrate_options.pop("simulator", None)
    method = calibrate_options.pop("method", None)
    # SBC's prior takes the functional theta's and a deliberately wrong program's forms otherwise; not this family
    if calibrate_options.pop("program", None) is not None or functional_parametrizations(calibrate_options) != (
            None, None):
        raise SystemExit(f"{FAMILY}'s options changed: the prior run no longer mirrors SBC's")
    prior_model = model_keywords(calibrate_options, vector=False)  # takes the model's keywords out of the options
    prior_model["discrepancy_parametrization"] = "non_centred"  # as SBC's prior (centred is a funnel there)
    print(f"calibrate(data, simulator={simulator}, method={method!r}, prior=True, chains=1, "
          f"warmup={PRIOR_WARMUP}, seed={seed}, draws={draws}, **{calibrate_options}, **{prior_model})", flush=True)
    started = time.perf_counter()
    fit = calibrate(data, simulator=simulator, method=method, prior=True, chains=1, warmup=PRIOR_WARMUP,
                    seed=seed, draws=draws, **calibrate_options, **prior_model)
    return data, fit, time.perf_counter() - started


def prior_draws(fit, data: stancal.CalibrationData) -> dict[str, np.ndarray]:
    """Every draw's y_rep and its own noise parameters (chains=1: in order), with the Stan data's noise
    locations, rows' locations and scaling: all the generator check reads, and what it saves."""
    stan_data = fit_stan_data(fit)
    y_rep = np.asarray(fit.idata["prior_predictive"]["y"]).reshape(-1, len(data.physical))
    par = fit.idata["prior_stan_parameters"]
    first = {name: np.asarray(par[name]).reshape(len(y_rep), -1)[:, 0]
             for name in ("noise_sd", "noise_gp_sd", "noise_length_scale")}
    return {"y_rep": y_rep, **first, "noise_z": np.asarray(par["noise_z"]).reshape(len(y_rep), -1),
            "x_noise": np.asarray(stan_data["x_noise"], float),
            "noise_loc": np.asarray(stan_data["noise_loc"], int) - 1,  # Stan's 1-based
            "y_center": float(stan_data["y_center"]), "y_scale": float(stan_data["y_scale"]),
            "t": data.physical["t"].to_numpy(float), "T0": data.physical["T0"].to_numpy(float)}


def stan_data_agreement(draws: dict, design: Design, data: stancal.CalibrationData) -> dict[str, bool]:
    """Do the program's noise locations and scaling agree with the design `ranks` uses, and with the run's?"""
    scaling = design.data.scaling
    return {"x_noise": bool(np.allclose(draws["x_noise"][:, 0], design.unit_t)),
            "noise_loc": bool(np.array_equal(draws["noise_loc"], design.location)),
            "y_center": bool(np.isclose(draws["y_center"], scaling.y_center)),
            "y_scale": bool(np.isclose(draws["y_scale"], scaling.y_scale)),
            "scaling_of_run": bool(np.isclose(draws["y_scale"], data.scaling.y_scale)
                                   and np.isclose(draws["y_center"], data.scaling.y_center))}


def draw_scatter(draws: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Each draw's per-setting sums of squares (standardised), each draw's location sds, each setting's
    location, and each row's setting."""
    setting = settings_of(draws["t"], draws["T0"])
    shapes = np.array([log_sd_shape(draws["x_noise"][:, 0], gp_sd, ls, z) for gp_sd, ls, z in
                       zip(draws["noise_gp_sd"], draws["noise_length_scale"], draws["noise_z"], strict=True)])
    y_std = (draws["y_rep"] - draws["y_center"]) / draws["y_scale"]
    sd_loc = draws["noise_sd"][:, None] * np.exp(shapes)
    return setting_squares(y_std, setting), sd_loc, setting_locations(setting, draws["noise_loc"]), setting


def analyse_draws(draws: dict) -> tuple[dict, np.ndarray]:
    """Q of every draw against chi2(60), each setting's term against chi2(3), and whether the lower
    tail depends on the parameters (a fault would be systematic in some of them). Also returns Q."""
    raw, sd_loc, set_loc, setting = draw_scatter(draws)
    dof, sigma = dof_of(setting), draws["noise_sd"]
    per_set = raw / sd_loc[:, set_loc] ** 2
    q = per_set.sum(axis=1)
    report: dict = {"Q": summary(q, dof), "settings": []}
    for j in range(per_set.shape[1]):
        rows = setting == j
        s = summary(per_set[:, j], int(rows.sum() - 1))
        s.update(t=float(draws["t"][rows][0]), T0=float(draws["T0"][rows][0]), location=int(set_loc[j]))
        report["settings"].append(s)
    report["settings_pooled"] = summary(per_set.ravel(), 3)
    set_ks = np.array([s["ks_p"] for s in report["settings"]])
    report["settings_ks_p_min"] = float(set_ks.min())
    report["settings_ks_p_fisher"] = float(stats.combine_pvalues(set_ks).pvalue)
    u = stats.chi2.cdf(q, dof)
    report["spearman_cdf_vs"] = {name: float(stats.spearmanr(u, draws[name]).statistic)
                                 for name in ("noise_sd", "noise_gp_sd", "noise_length_scale")}
    deciles = np.quantile(sigma, np.linspace(0, 1, 11))
    bins = np.clip(np.searchsorted(deciles, sigma, side="right") - 1, 0, 9)
    report["lowest_tenth_by_noise_sd_decile"] = [float(np.mean(u[bins == b] < 0.1)) for b in range(10)]
    report["mean_Q_over_dof_by_noise_sd_decile"] = [float(np.mean(q[bins == b]) / dof) for b in range(10)]
    return report, q


def thinned_indices(length: int, count: int) -> np.ndarray:
    """The draws sbc.py's prior run keeps: ``count`` evenly spaced over ``length``, rounded."""
    return np.linspace(0, length - 1, count).round().astype(int)


def cross_check(draws: dict, q: np.ndarray, design: Design, fits: Path | None) -> dict:
    """SBC's truths (FITS_DIR's truth.json) found among the run's draws; how long SBC's prior run was, by
    which lengths' thinning picks those draws; their Q against `ranks`' Q of the same simulated data."""
    truths = {} if fits is None else {int(p.name): json.loads((p / "truth.json").read_text())["stan_parameters"]
                                      for p in sorted(fits.iterdir()) if (p / "truth.json").is_file()}
    if not truths:
        return {}
    matched = {}
    for sim, p in truths.items():
        hit = np.flatnonzero(np.all(np.isclose(draws["noise_z"], np.asarray(p["noise_z"])[None, :], rtol=0,
                                               atol=1e-12), axis=1)
                             & np.isclose(draws["noise_sd"], p["noise_sd"][0], rtol=0, atol=1e-12))
        if len(hit) == 1:
            matched[sim] = int(hit[0])
    cross: dict = {"truths": len(truths), "matched": len(matched)}
    if not matched:
        return cross
    sims = np.array(sorted(matched))
    idx = np.array([matched[s] for s in sims])
    lengths = [n for n in range(SIMULATIONS, len(q) + 1)
               if np.array_equal(thinned_indices(n, SIMULATIONS)[sims], idx)]
    cross["sbc_prior_draws_consistent"] = lengths[:5]
    if lengths:
        cross["Q_sbc_thinned_all_200"] = summary(q[thinned_indices(lengths[0], SIMULATIONS)], dof_of(design.setting))
    finished = [s for s in sims if (fits / f"{s:04d}" / "finished.json").is_file()]  # those `ranks` reads
    if finished:
        data = {s: simulated_data(fits / f"{s:04d}")[0] for s in finished}
        ranks_q = {s: true_scatter(data[s], truths[s], design)[0] / truths[s]["noise_sd"][0] ** 2 for s in finished}
        cross["Q_vs_ranks_max_abs_diff"] = float(max(abs(q[matched[s]] - ranks_q[s]) for s in finished))
        cross["Q_vs_ranks_compared"] = len(finished)
        first = finished[0]
        cross["y_rep_equals_sbc_data_first_match"] = bool(np.allclose(draws["y_rep"][matched[first]], data[first]))
    return cross


def jitter_check(draws: dict) -> dict:
    """Q again with a per-row extra variance e beside s_loc^2: gp_conditional_draw
    (stan_models/functions/gp_conditional.stan) adds 1e-6 x the mean diagonal of the prior covariance of
    (f, delta) to each row's draw, independently per row, so replicates differ by it too. e is the median
    estimate over the draws whose smallest location sd is below TINY_SD, where it dominates."""
    raw, sd_loc, set_loc, setting = draw_scatter(draws)
    n, dof = len(raw), dof_of(setting)
    var_set = sd_loc[:, set_loc] ** 2
    tiny = sd_loc.min(axis=1) < TINY_SD
    # each setting's sum of squares has mean 3 (var + e): 4 replicates, 3 degrees of freedom
    e_hat = (raw.sum(axis=1) - 3 * var_set.sum(axis=1)) / (3 * raw.shape[1])
    extra = float(np.median(e_hat[tiny]))
    out: dict = {"draws_smallest_location_sd_below_0.01": int(np.sum(sd_loc.min(axis=1) < 0.01)),
                 f"draws_smallest_location_sd_below_{TINY_SD}": int(tiny.sum()), "extra_variance": extra,
                 "extra_sd_standardised": float(np.sqrt(extra)),
                 "extra_sd_original": float(np.sqrt(extra) * draws["y_scale"])}
    for name, e in (("without_extra", 0.0), ("with_extra", extra)):
        per_set = raw / (var_set + e)
        q = per_set.sum(axis=1)
        u = stats.chi2.cdf(q, dof)
        out[name] = {"Q": summary(q, dof), "settings_pooled": summary(per_set.ravel(), 3),
                     "cdf_above_0.999": int(np.sum(u > 0.999)), "cdf_above_0.9999": int(np.sum(u > 0.9999)),
                     "expected_above_0.999": n / 1000}
        s, p = out[name]["Q"], out[name]["settings_pooled"]
        print(f"{name} (e = {e:.2e}): Q KS p {s['ks_p']:.3f}, lowest tenth {s['lowest_tenth_frac']:.4f}, mean Q/60 "
              f"{s['mean_over_dof']:.4f}, var/120 {s['var_over_2dof']:.3g}, CDF > 0.999: {out[name]['cdf_above_0.999']}"
              f" (expected {n / 1000:.0f}); per setting pooled KS p {p['ks_p']:.3f}, mean/3 {p['mean_over_dof']:.4f}")
    return out


def print_generator(report: dict) -> None:
    qs, pooled, cross = report["Q"], report["settings_pooled"], report["sbc_cross_check"]
    print(f"{report['draws']} draws; Q ~ chi2({qs['dof']}): KS p = {qs['ks_p']:.3g}; tenths {qs['tenths']}; lowest "
          f"tenth {qs['lowest_tenth']} = {qs['lowest_tenth_frac']:.4f} (binomial two-sided p = "
          f"{qs['lowest_tenth_binom_p_two_sided']:.3g}); mean Q/60 = {qs['mean_over_dof']:.4f} "
          f"(se {qs['mean_over_dof_se']:.4f}); var/120 = {qs['var_over_2dof']:.3f}; lag-1 autocorr of CDF "
          f"{qs['lag1_autocorr_cdf']:+.3f}, of Q {qs['lag1_autocorr_stat']:+.3f}")
    print(f"per setting (chi2(3)): pooled KS p = {pooled['ks_p']:.3g}, lowest tenth {pooled['lowest_tenth_frac']:.4f} "
          f"(p = {pooled['lowest_tenth_binom_p_two_sided']:.3g}), mean/3 = {pooled['mean_over_dof']:.4f} "
          f"(se {pooled['mean_over_dof_se']:.4f}); per-setting KS p min {report['settings_ks_p_min']:.3g}, "
          f"Fisher-combined {report['settings_ks_p_fisher']:.3g}")
    for s in report["settings"]:
        print(f"  t={s['t']:g} T0={s['T0']:g} loc {s['location']}: KS p {s['ks_p']:.3f}, low tenth "
              f"{s['lowest_tenth_frac']:.3f} (p {s['lowest_tenth_binom_p_two_sided']:.3f}), mean/3 "
              f"{s['mean_over_dof']:.3f}, lag1 {s['lag1_autocorr_cdf']:+.3f}")
    print(f"Spearman(CDF(Q), .) {report['spearman_cdf_vs']}")
    print(f"lowest-tenth fraction by noise_sd decile {np.round(report['lowest_tenth_by_noise_sd_decile'], 3).tolist()}")
    print(f"mean Q/60 by noise_sd decile {np.round(report['mean_Q_over_dof_by_noise_sd_decile'], 3).tolist()}")
    print(f"SBC cross-check: {json.dumps({k: v for k, v in cross.items() if k != 'Q_sbc_thinned_all_200'})}")
    if "Q_sbc_thinned_all_200" in cross:
        c = cross["Q_sbc_thinned_all_200"]
        print(f"  the 200 draws SBC thinned: KS p {c['ks_p']:.3f}, tenths {c['tenths']}, lowest tenth "
              f"{c['lowest_tenth']} (upper p {c['lowest_tenth_binom_p_upper']:.3f}), mean Q/60 "
              f"{c['mean_over_dof']:.3f}")


def generator(args: argparse.Namespace) -> None:
    if args.reanalyse:  # no prior run: the jitter check on saved draws, added to OUT's report
        report = json.loads(args.out.read_text()) if args.out.is_file() else {}
        report["jitter_check"] = jitter_check(dict(np.load(args.reanalyse)))
        write_json(args.out, report)
        print(f"written {args.out}")
        return
    design = Design.load()
    data, fit, seconds = prior_run(args.draws, args.seed)
    timing = {k: float(v) for k, v in fit.timing.items()}
    print(f"prior run: {seconds:.0f} s wall; timing {timing}", flush=True)
    if timing.get("compile_s", 0.0) > 0:
        print("WARNING: something was compiled: the options may differ from SBC's", flush=True)
    draws = prior_draws(fit, data)
    agree = stan_data_agreement(draws, design, data)
    print(f"Stan data vs the design `ranks` uses: {agree}; N_loc {len(draws['x_noise'])}, "
          f"D_noise {draws['x_noise'].shape[1]}", flush=True)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(args.out.with_suffix(".npz"), **draws)  # for --reanalyse, without another run
    analysis, q = analyse_draws(draws)
    report = {"command": " ".join(sys.argv), "draws": len(q), "seed": args.seed, "seconds": seconds,
              "timing": timing, "stan_data_agrees_with_design": agree, **analysis,
              "sbc_cross_check": cross_check(draws, q, design, args.fits)}
    print_generator(report)
    report["jitter_check"] = jitter_check(draws)
    write_json(args.out, report)
    print(f"written {args.out}")


def paired(args: argparse.Namespace) -> None:
    """Each simulation fitted in both runs: the longer fits' ranks less the short fits', per parameter."""
    design = Design.load()
    both = sorted(p.name for p in args.long_fits.iterdir() if (p / "finished.json").is_file()
                  and (args.short_fits / p.name / "finished.json").is_file())
    short, long = ([simulation(folder / name, design).record for name in both]
                   for folder in (args.short_fits, args.long_fits))
    if any(a["noise_sd_true"] != b["noise_sd_true"] for a, b in zip(short, long, strict=True)):
        raise SystemExit("the two runs' truths differ: not the same simulations")
    report = {"short_fits": str(args.short_fits), "long_fits": str(args.long_fits), "simulations": len(both),
              "parameters": {}}
    for name in short[0]["ranks_all"]:
        diff = np.array([b["ranks_all"][name] - a["ranks_all"][name] for a, b in zip(short, long, strict=True)])
        report["parameters"][name] = {
            "mean_long_minus_short": float(diff.mean()), "se": float(diff.std(ddof=1) / np.sqrt(len(diff))),
            "t_test_p": float(stats.ttest_1samp(diff, 0).pvalue),
            "mean_short": float(np.mean([a["ranks_all"][name] for a in short])),
            "mean_long": float(np.mean([b["ranks_all"][name] for b in long]))}
    reference = np.array([a["reference_rank"] for a in short])
    for label, run in (("short", short), ("long", long)):
        diff = np.array([r["rank_norm"] for r in run]) - reference
        report[f"{label}_minus_reference"] = {"mean": float(diff.mean()),
                                              "se": float(diff.std(ddof=1) / np.sqrt(len(diff))),
                                              "t_test_p": float(stats.ttest_1samp(diff, 0).pvalue)}
    noise = report["parameters"][NOISE]
    report["verdict"] = ("sampler: the longer fits rank the noise sd's truth lower by more than 2 se"
                         if noise["mean_long_minus_short"] < -2 * noise["se"] else
                         "model: the longer fits do not rank the noise sd's truth lower by more than 2 se")
    print(f"{len(both)} simulations fitted in both runs")
    for name, v in report["parameters"].items():
        print(f"  {name}: long - short {v['mean_long_minus_short']:+.4f} (se {v['se']:.4f}, p = {v['t_test_p']:.3f});"
              f" mean rank/L short {v['mean_short']:.3f}, long {v['mean_long']:.3f}")
    for label in ("short", "long"):
        v = report[f"{label}_minus_reference"]
        print(f"  noise sd, {label} fits - exact reference: {v['mean']:+.4f} (se {v['se']:.4f}, "
              f"p = {v['t_test_p']:.3f})")
    print(report["verdict"])
    write_json(args.out, report)
    print(f"written {args.out}")


def written(args: argparse.Namespace) -> None:
    """The written-out SBC's simulations (benchmarks/sbc_written_out.py) against the same exact reference:
    each truth and data set drawn again from its seed, its W and reference rank beside the fit's rank."""
    import sbc_written_out as wo

    design = Design.load()
    done = sorted((json.loads(line) for line in args.ranks_jsonl.read_text().splitlines()),
                  key=lambda r: r["simulation"])
    _, _, d = wo.setup(args.seed)
    sims = []
    for record in done:
        p, y_std = wo.simulation(d, args.seed, record["simulation"])  # as the script drew it
        sigma = float(p["noise_sd"][0])
        if abs(sigma * d["y_scale"] - record["truth"][NOISE]) > 1e-9 * record["truth"][NOISE]:
            raise SystemExit(f"simulation {record['simulation']}: the truth drawn again differs from the kept one")
        shape = log_sd_shape(design.unit_t, p["noise_gp_sd"][0], p["noise_length_scale"][0], p["noise_z"])
        w = scatter_w(y_std, design.setting, design.location, shape)
        sims.append({"simulation": record["simulation"], "rank_norm": record["ranks"][NOISE] / wo.DRAWS_PER_FIT,
                     "Q": w / sigma**2, "Q_cdf": float(stats.chi2.cdf(w / sigma**2, design.dof)),
                     "reference_rank": float(reference_cdf(w, sigma, design.dof)[0])})
    report = {"ranks": str(args.ranks_jsonl), "seed": args.seed, "simulations": len(sims),
              **ranks_summary(sims, args.seed, design.dof)}
    q, r, pr = report["Q"], report["reference"], report["paired"]
    print(f"{len(sims)} written-out simulations: Q lowest tenth {q['lowest_tenth']} (KS p {q['ks_p_chi2']:.3f}), "
          f"Spearman(rank, Q) {q['spearman_rank_vs_Q']:.2f}; reference gamma p {r['gamma_p']:.3f}; paired fit - "
          f"reference {pr['mean_fit_minus_reference']:+.4f} (sd {pr['sd']:.3f}, t p {pr['t_test_p']:.4f}, "
          f"Wilcoxon p {pr['wilcoxon_p']:.4f})")
    write_json(args.out, report)
    print(f"written {args.out}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    commands = parser.add_subparsers(dest="command", required=True)
    check = commands.add_parser("ranks", help="a finished SBC run, simulation by simulation")
    check.add_argument("fits_dir", type=Path, metavar="FITS_DIR", help="OUT/modular_heteroscedastic/fits")
    check.add_argument("--out", type=Path, default=Path("sbc_heteroscedastic_ranks.json"))
    check.add_argument("--toy", type=int, default=10000, help="toy simulations of the reference (0: skip)")
    check.set_defaults(run=ranks)
    pair = commands.add_parser("paired", help="two runs' fits of the same simulations, rank by rank")
    pair.add_argument("short_fits", type=Path, metavar="SHORT_FITS", help="the default fits' OUT/FAMILY/fits")
    pair.add_argument("long_fits", type=Path, metavar="LONG_FITS", help="the longer fits' OUT/FAMILY/fits")
    pair.add_argument("--out", type=Path, default=Path("sbc_heteroscedastic_paired.json"))
    pair.set_defaults(run=paired)
    prior = commands.add_parser("generator", help="one long prior run: every draw's Q")
    prior.add_argument("--draws", type=int, default=4000)
    prior.add_argument("--seed", type=int, default=2, help="the prior run's seed (SBC's, to find its truths)")
    prior.add_argument("--out", type=Path, default=Path("sbc_heteroscedastic_generator.json"),
                       help="the report; the draws are saved beside it (.npz)")
    prior.add_argument("--fits", type=Path, default=None, metavar="FITS_DIR",
                       help="the SBC run (same seed) whose truths are found among the draws")
    prior.add_argument("--reanalyse", type=Path, default=None, metavar="NPZ",
                       help="no prior run: the jitter check on the draws saved in NPZ, added to OUT")
    prior.set_defaults(run=generator)
    out = commands.add_parser("written", help="the written-out SBC's simulations against the exact reference")
    out.add_argument("ranks_jsonl", type=Path, metavar="RANKS_JSONL", help="sbc_written_out.py's OUT/ranks.jsonl")
    out.add_argument("--seed", type=int, default=2, help="that run's --seed")
    out.add_argument("--out", type=Path, default=Path("sbc_heteroscedastic_written.json"))
    out.set_defaults(run=written)
    args = parser.parse_args()
    args.run(args)


if __name__ == "__main__":
    main()
