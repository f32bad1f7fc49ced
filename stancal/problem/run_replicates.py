"""Replicated simulator runs: runs whose inputs and theta are equal, found
by exact equality. A deterministic simulator repeats itself there; a
stochastic one (agent-based, Monte Carlo) scatters, and that scatter is the
simulator's own (intrinsic) variance, which the emulator of its mean carries
(stochastic kriging, Ankenman, Nelson & Staum 2010; docs/noise.md). The
counts and the pooled within-replicate sd go to the log, summary.json and
the report, stochastic or not."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def pooled_variance(counts: np.ndarray, variances: np.ndarray) -> float:
    """Sample variances of replicated settings (``counts`` runs each, >= 2)
    pooled: sum (n_i - 1) s_i^2 / sum (n_i - 1)."""
    dof = np.asarray(counts, float) - 1
    return float(np.sum(dof * np.asarray(variances, float)) / dof.sum())


def group_settings(settings: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rows of ``settings`` (M, K), or values (M,), grouped where exactly equal: the distinct
    rows, each row's group (an index into them) and each group's size."""
    rows = np.asarray(settings, float)
    distinct, index, counts = np.unique(rows.reshape(len(rows), -1), axis=0, return_inverse=True,
                                        return_counts=True)
    return distinct, index.ravel(), counts


@dataclass(frozen=True)
class RunReplicates:
    """The runs grouped by their setting (inputs and theta)."""

    settings: np.ndarray  # (S, D + Q): each distinct setting, as given
    setting_of_run: np.ndarray  # (M,): each run's setting, an index into settings
    counts: np.ndarray  # (S,): runs per setting
    means: np.ndarray  # (S,): the mean output of each setting's runs
    variances: np.ndarray  # (S,): the sample variance (ddof 1) of each setting's runs; nan for one run

    @classmethod
    def of(cls, settings: np.ndarray, output: np.ndarray) -> RunReplicates:
        """Group the runs' ``settings`` (M, D + Q) and ``output`` (M,)."""
        distinct, index, counts = group_settings(settings)
        y = np.asarray(output, float)
        sums = np.bincount(index, y, len(counts))
        means = sums / counts
        squares = np.bincount(index, (y - means[index]) ** 2, len(counts))
        with np.errstate(invalid="ignore", divide="ignore"):
            variances = np.where(counts > 1, squares / (counts - 1), np.nan)
        return cls(distinct, index, counts, means, variances)

    @property
    def replicated(self) -> np.ndarray:
        """The settings run more than once."""
        return self.counts > 1

    def pooled_variance(self) -> float:
        """The within-replicate variance pooled over the replicated settings,
        sum (n_i - 1) s_i^2 / sum (n_i - 1); nan without replicates."""
        if not self.replicated.any():
            return float("nan")
        return pooled_variance(self.counts[self.replicated], self.variances[self.replicated])

    def summary(self, scale: float = 1.0) -> dict:
        """For summary.json and the report: the runs, the settings, those run
        more than once, the runs per replicated setting (min, median, max) and
        the pooled within-replicate sd times ``scale`` (the output's units)."""
        runs = self.counts[self.replicated]
        pooled = self.pooled_variance()
        return {"runs": int(self.counts.sum()), "settings": len(self.counts),
                "replicated_settings": int(self.replicated.sum()),
                "runs_per_replicated_setting": ([int(runs.min()), float(np.median(runs)), int(runs.max())]
                                                if len(runs) else []),
                "pooled_within_replicate_sd": None if np.isnan(pooled) else float(np.sqrt(pooled) * scale)}


def describe(summary: dict) -> str:
    """One line for the log and the report."""
    if not summary["replicated_settings"]:
        return f"no replicated runs ({summary['runs']} runs at {summary['settings']} distinct settings)"
    low, median, high = summary["runs_per_replicated_setting"]
    return (f"{summary['replicated_settings']} of {summary['settings']} run settings (inputs and theta) are "
            f"replicated, {low}-{high} runs each (median {median:g}); pooled within-replicate sd "
            f"{summary['pooled_within_replicate_sd']:.4g}")
