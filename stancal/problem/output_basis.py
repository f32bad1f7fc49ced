"""The reduced basis of vector simulator output (Higdon et al. 2008,
"Computer model calibration using high-dimensional output", JASA 103,
section 2.1): principal components of the standardised runs.

Each run returns a vector over one shared grid of output indices (times,
positions, features). The runs are centred by their mean vector and scaled
by one overall sd (one sd, not one per index, so that a component's
share of variance is a share of the output's own variance); their SVD gives
the components, kept until they explain a share of the variance or to a
given number. An emulator then needs one GP per component weight instead of
one per grid value, and the variance the kept components leave (the
truncation error) enters the likelihood as GPMSA's does.

Experiments are observed at their own indices, which need not lie on the
runs' grid: the mean vector and the components are interpolated there,
linearly (piecewise-linear in one index; over the Delaunay triangulation of
the grid for a field).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import LinearNDInterpolator

from stancal.problem.validation import DataError

# The components left out are not noise: they are the runs' smaller patterns, functions of (x, theta)
# like the kept ones, and they still carry theta's information wherever they exceed the measurement
# error. The likelihood takes what they leave as independent noise, so that must be small against
# the measurements: 99.99 % leaves a truncation sd of 1 % of the runs' sd. On SEPIA's Neddermeyer
# implosion (docs/neddermeyer.md; Higdon et al. 2008 keep 3 components there) 99.5 % kept one
# component, left a truncation sd of 0.025 cm against 0.01 cm of noise, and theta's posterior sd was
# 0.83 of its prior's; 99.99 % keeps the example's 3 (0.0027 cm) and theta's sd is 0.09 of its prior's.
DEFAULT_VARIANCE_SHARE = 0.9999


@dataclass(frozen=True)
class OutputBasis:
    """y(index) ~ mean(index) + scale * components(index) @ weights."""

    grid: np.ndarray  # (K, index columns): the runs' shared output indices
    mean: np.ndarray  # (K,)
    scale: float  # one sd over all runs and indices
    components: np.ndarray  # (K, p): orthonormal over the grid, times their singular value / sqrt(N)
    explained: np.ndarray  # (p,): each component's share of the standardised runs' variance
    truncation_variance: float  # per grid value, standardised units: what the p components leave
    interpolation_variance: float = 0.0  # per value off the grid, standardised units (interpolation_variance)

    @classmethod
    def from_runs(cls, grid: np.ndarray, outputs: np.ndarray, variance_share: float = DEFAULT_VARIANCE_SHARE,
                  components: int | None = None) -> OutputBasis:
        """``outputs``: (runs, K) on ``grid`` (K rows). Keep ``components``
        if given, else the fewest whose share of variance reaches ``variance_share``."""
        grid = np.asarray(grid, float).reshape(len(outputs[0]), -1)
        outputs = np.asarray(outputs, float)
        runs = len(outputs)
        if not 0 < variance_share <= 1:
            raise ValueError(f"variance_share must lie in (0, 1]; got {variance_share}")
        mean = outputs.mean(axis=0)
        scale = float((outputs - mean).std())
        if scale == 0:
            raise DataError("simulator runs: every run returns the same output vector")
        standardised = (outputs - mean) / scale
        left, singular, right_t = np.linalg.svd(standardised, full_matrices=False)
        share = singular**2 / np.sum(singular**2)
        count = (components if components is not None
                 else int(np.searchsorted(np.cumsum(share), variance_share - 1e-12) + 1))
        # centred runs span at most runs - 1 directions: a basis that needs all of them has too few runs
        # to tell the output's variation apart from the runs' own
        if count >= runs - 1:
            raise DataError(f"simulator runs: {runs} runs for {count} output components "
                            f"({'asked for' if components is not None else f'{variance_share:.1%} of the variance'}); "
                            f"the emulator needs more runs than components: add runs, or keep fewer components")
        if count > len(share):
            raise DataError(f"simulator runs: {count} components asked for, but the runs span only {len(share)}")
        kept = right_t[:count].T * singular[:count] / np.sqrt(runs)
        residual = standardised - (left[:, :count] * singular[:count]) @ right_t[:count]
        return cls(grid, mean, scale, kept, share[:count], float(np.mean(residual**2)),
                   interpolation_variance(grid, outputs / scale))  # the mean curve is interpolated too

    def independent_variance_at(self, indices: np.ndarray) -> np.ndarray:
        """What the likelihood adds to each of M values at M output indices
        as independent error (M,), standardised units: the truncation error everywhere, the
        interpolation error only off the grid. At a grid value the mean and
        the components are the runs' own, so nothing is interpolated; for a
        feature set (velocities at named points, Al-5083) every value sits on
        the grid, and an error estimated between unrelated neighbouring
        features would drown the measurements (there 42 m/s against a noise
        of 1.5-2.2 m/s)."""
        indices = self._index_rows(indices)
        # to rounding, not exactly: a value a few ulps off a grid index is interpolated from that grid value
        # alone, and an exact test would load Al-5083's 42 m/s onto it. (same_point in
        # stancal.numerics.vector_emulator groups exactly: its grouping must be an equivalence, for a PSD matrix.)
        on_grid = np.isclose(indices[:, None, :], self.grid[None, :, :], rtol=1e-12, atol=0).all(axis=2).any(axis=1)
        return self.truncation_variance + np.where(on_grid, 0.0, self.interpolation_variance)

    def _index_rows(self, indices: np.ndarray) -> np.ndarray:
        """M output indices as (M, index columns) floats."""
        return np.asarray(indices, float).reshape(-1, self.grid.shape[1])

    @property
    def count(self) -> int:
        return self.components.shape[1]

    def weights(self, outputs: np.ndarray) -> np.ndarray:
        """(runs, p): least-squares weights of output vectors on the grid
        (for the runs, their principal-component scores, of unit variance)."""
        standardised = (np.asarray(outputs, float) - self.mean) / self.scale
        return np.linalg.lstsq(self.components, standardised.T, rcond=None)[0].T

    def project(self, grid: np.ndarray, outputs: np.ndarray) -> np.ndarray:
        """(runs, p): least-squares weights of other runs' output vectors on
        their own ``grid`` (K' rows, within this basis's grid), standardised
        with this basis's mean and scale: a cheaper simulator's runs on the
        calibrated one's basis (docs/multifidelity.md). The mean and the
        components are interpolated at the grid as at an experiment's
        ragged indices (``at``); on this basis's own grid they are its own,
        and this is ``weights``. DataError when the components interpolated
        at ``grid`` do not have full rank (the weights would not be determined)."""
        try:
            mean, components = self.at(grid)
        except DataError as err:  # the cheaper runs' grid reaches beyond the calibrated simulator's
            raise DataError(f"low-fidelity runs: {err}; the basis cannot extrapolate") from None
        if len(mean) < self.count:
            raise DataError(f"low-fidelity runs: {len(mean)} output indices for {self.count} basis components; "
                            f"their runs need at least as many indices as components")
        standardised = (np.asarray(outputs, float) - mean) / self.scale
        weights, _, rank, _ = np.linalg.lstsq(components, standardised.T, rcond=None)
        if rank < self.count:  # lstsq's minimum-norm answer would pass for the weights
            rows = self._index_rows(grid)
            span = (f"{rows[:, 0].min():g} to {rows[:, 0].max():g}" if rows.shape[1] == 1
                    else "within the basis's grid")
            raise DataError(f"low-fidelity runs: their grid ({len(rows)} output indices, {span}) determines {rank} "
                            f"of the {self.count} basis components' weights; spread their indices over the runs' grid")
        return weights.T

    def at(self, indices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The mean (M,) and components (M, p) interpolated at M output
        indices, each within the grid's range (DataError otherwise)."""
        indices = self._index_rows(indices)
        values = np.column_stack([self.mean, self.components])
        if self.grid.shape[1] == 1:
            order = np.argsort(self.grid[:, 0])
            lo, hi = self.grid[order[0], 0], self.grid[order[-1], 0]
            outside = (indices[:, 0] < lo) | (indices[:, 0] > hi)
            if outside.any():
                raise DataError(f"output indices {indices[outside, 0][:5].tolist()} lie outside the runs' grid "
                                f"[{lo:g}, {hi:g}]")
            out = np.column_stack([np.interp(indices[:, 0], self.grid[order, 0], v[order]) for v in values.T])
        else:
            out = LinearNDInterpolator(self.grid, values)(indices)
            outside = np.isnan(out).any(axis=1)
            if outside.any():
                raise DataError(f"output indices {indices[outside][:5].tolist()} lie outside the runs' grid "
                                f"(its convex hull)")
        return out[:, 0], out[:, 1:]

    def predict(self, indices: np.ndarray, weight_mean: np.ndarray,
                weight_variance: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The output's mean and variance (points, M) at M output indices,
        from its weights' predictive means and variances (points, p); the
        weights are independent, and the truncation error adds to every
        value, the interpolation error to those off the grid."""
        mean_vector, components = self.at(indices)
        mean = mean_vector + self.scale * weight_mean @ components.T
        variance = self.scale**2 * (weight_variance @ (components**2).T + self.independent_variance_at(indices))
        return mean, variance

    def describe(self) -> str:
        return (f"{self.count} components explain {self.explained.sum():.2%} of the runs' variance "
                f"({', '.join(f'{s:.1%}' for s in self.explained[:6])}{', ...' if self.count > 6 else ''})")


def interpolation_variance(grid: np.ndarray, scaled: np.ndarray) -> float:
    """The mean squared error of interpolating the runs (``scaled``: divided
    by the basis's sd, not centred, as the mean curve is interpolated too)
    linearly between grid values. For one index column, each interior grid
    value is predicted from its two neighbours, an interval twice the
    grid's; for a curve of locally constant curvature the error at s within
    an interval h is f'' s (h - s) / 2, whose mean square over s is
    f''^2 h^4 / 120, and the error from the neighbours is f'' h^2 / 2 at the
    doubled interval's middle: the mean square within the grid's own
    intervals is that error's square / 30. Without it, a basis that keeps
    the runs' variance to 99.99 % leaves the off-grid error out of the bands
    (held-out cooling curves: 77 % inside the 90 % bands; with it, 91 %).
    For a field on a tensor grid of two index columns, the sum of that
    estimate along each column's lines: the triangulation's linear
    interpolant also feels the mixed derivative, which the sum leaves out
    (measured 0.83-0.91 of its error on smooth fields). Other fields: 0, not
    estimated."""
    if grid.shape[1] == 1:
        return _line_variance(grid[:, 0], scaled)
    if grid.shape[1] != 2 or not _is_tensor(grid):
        return 0.0
    return float(sum(np.mean([_line_variance(grid[line, axis], scaled[:, line]) for line in _lines(grid, axis)])
                     for axis in range(grid.shape[1])))


def _line_variance(t: np.ndarray, scaled: np.ndarray) -> float:
    """interpolation_variance along one index (the values at ``t``)."""
    if len(t) < 3:
        return 0.0
    order = np.argsort(t)
    t, values = t[order], scaled[:, order]
    weight = (t[1:-1] - t[:-2]) / (t[2:] - t[:-2])
    error = values[:, 1:-1] - ((1 - weight) * values[:, :-2] + weight * values[:, 2:])
    return float(np.mean(error**2) / 30)


def _is_tensor(grid: np.ndarray) -> bool:
    """The grid holds every combination of its columns' values, once each."""
    counts = [len(np.unique(grid[:, c])) for c in range(grid.shape[1])]
    return len(np.unique(grid, axis=0)) == len(grid) == int(np.prod(counts))


def _lines(grid: np.ndarray, axis: int) -> list[np.ndarray]:
    """A tensor grid's lines along ``axis``: the rows where every other column is fixed."""
    others = np.delete(grid, axis, axis=1)
    return [np.flatnonzero((others == key).all(axis=1)) for key in np.unique(others, axis=0)]
