"""Discrepancy mean terms h(x, z)' beta from a formula over the physical
data's columns (review section 4.1: a regression mean for delta), built with
formulaic so users write the formulas they know from R and statsmodels."""

from __future__ import annotations

import re
import warnings
from dataclasses import dataclass

import numpy as np
import pandas as pd

INTERCEPT_PRIOR_SD = 10.0  # standardised output units: effectively flat


class FormulaError(ValueError):
    """A mean formula that cannot be evaluated on the data."""


def _plain(message: object) -> str:
    """formulaic's message on one line, without terminal colours."""
    text = re.sub(r"\x1b\[[0-9;]*m|[\u29da\u29db]", "", str(message))
    return " ".join(text.split())


@dataclass(frozen=True)
class MeanTerms:
    """The terms of one formula, each column scaled to unit root mean square
    over the physical points so that beta ~ N(0, 1) is weakly informative.
    Beside a constant term, every other column is centred at its mean over
    the physical points first: a term nearly constant there (air pressure,
    1016 +- 5 hPa) would otherwise be collinear with the constant, and the
    sampler would crawl along the ridge between them. The constant is then
    the discrepancy's level at the mean of the terms."""

    formula: str
    names: list[str]
    center: np.ndarray  # subtracted from each raw column (zero for the constant, or without one)
    scale: np.ndarray  # root mean square of each centred column
    h: np.ndarray  # (N, H) centred, scaled terms at the physical points
    _spec: object  # formulaic ModelSpec, to evaluate at new points

    @property
    def prior_sd(self) -> np.ndarray:
        """N(0, 1) for each term. The intercept's prior is wide, so that the
        level of the discrepancy goes to it rather than to a term that is
        nearly constant (humidity in %, say) and would pass for an effect."""
        return np.where(np.array(self.names) == "Intercept", INTERCEPT_PRIOR_SD, 1.0)

    def at(self, frame: pd.DataFrame) -> np.ndarray:
        """Scaled terms at other points (same encoding of categories)."""
        from formulaic.errors import FormulaicError

        try:
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                raw = self._spec.get_model_matrix(frame, na_action="ignore")
        except (FormulaicError, ValueError, TypeError) as err:
            raise FormulaError(f"formula {self.formula!r} at new points: {_plain(err)}") from None
        for w in caught:  # formulaic codes unseen categories as the reference level
            if "categories" in str(w.message):
                raise FormulaError(f"formula {self.formula!r} at new points: {_plain(w.message)}")
        values = np.asarray(raw[self.names], dtype=float)
        bad = ~np.isfinite(values).all(axis=1)
        if bad.any():
            raise FormulaError(
                f"formula {self.formula!r}: missing values or unseen categories at new-point rows "
                f"{list(frame.index[bad][:10])}")
        return (values - self.center) / self.scale


def build_mean_terms(formula: str | None, physical: pd.DataFrame, intercept: bool = False,
                     centred: bool = False) -> MeanTerms:
    """Terms of ``formula``; categorical terms use treatment coding against
    their first level. Without ``intercept`` the GP carries the level; with
    it, a constant term ``Intercept`` comes first (``formula`` may then be None).
    ``centred``: centre the terms as beside a constant, without one (a
    calibration parameter carries the level: stancal.fitting.confounding)."""
    from formulaic import model_matrix
    from formulaic.errors import FormulaicError

    if formula is not None and not formula.strip():
        raise FormulaError("formula is empty")
    try:
        matrix = model_matrix("1" if formula is None else f"1 + ({formula})", physical,
                              na_action="raise")
    except (FormulaicError, ValueError, TypeError, SyntaxError) as err:
        raise FormulaError(f"formula {formula!r}: {_plain(err)}") from None
    names = [c for c in matrix.columns if intercept or c != "Intercept"]
    if formula is not None and names in ([], ["Intercept"]):
        raise FormulaError(f"formula {formula!r} has no terms besides a constant")
    values = np.asarray(matrix[names], dtype=float)
    center = np.where((intercept or centred) & (np.array(names) != "Intercept"), values.mean(axis=0), 0.0)
    scale = np.sqrt(np.mean((values - center) ** 2, axis=0))
    if (scale == 0).any():
        flat = [n for n, s in zip(names, scale, strict=True) if s == 0]
        raise FormulaError(f"formula {formula!r}: term(s) {flat} are "
                           + ("constant at every physical point, which the constant term already is"
                              if intercept else "constant at every physical point, which the calibration "
                              "parameter that carries the level already is" if centred
                              else "zero at every physical point"))
    return MeanTerms(formula, names, center, scale, (values - center) / scale, matrix.model_spec)
