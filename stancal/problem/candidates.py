"""Candidate unmodelled effects for the gap diagnosis: a formula of mean
terms over the physical columns, or a variant simulator written in Stan."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from stancal.problem.mean_terms import FormulaError, build_mean_terms
from stancal.problem.validation import DataError


class CandidateError(ValueError):
    """A candidate effect that cannot be fitted; the message names it."""



@dataclass(frozen=True)
class Candidate:
    """One candidate unmodelled effect: give ``formula``, or ``stan`` (a
    variant simulator) with the physical ``inputs`` it takes and the bounds
    of its extra ``theta`` (the baseline's theta keep theirs)."""

    name: str
    formula: str | None = None
    stan: Path | None = None
    inputs: tuple[str, ...] = ()
    theta: dict[str, tuple[float, float]] = field(default_factory=dict)

    @property
    def kind(self) -> str:
        return "formula" if self.formula is not None else "variant"

    def with_baseline_terms(self, baseline: str | None) -> str:
        """A formula candidate's mean terms beside the baseline's own (its
        mean_formula), which every fit of a gap diagnosis keeps."""
        return self.formula if baseline is None else f"({baseline}) + ({self.formula})"

    def __post_init__(self) -> None:
        if (self.formula is None) == (self.stan is None):
            raise CandidateError(f"candidate '{self.name}': give a formula or a Stan simulator, not both")
        if self.stan is not None and not self.inputs:
            raise CandidateError(f"candidate '{self.name}': a simulator variant needs its 'inputs' columns")


def variant_data(data, candidate: Candidate):
    """The physical data (a CalibrationData or VectorCalibrationData) as a
    simulator variant sees it (each container's variant()): its inputs must
    be physical columns, and its theta the variant's extra ones."""
    missing = [c for c in candidate.inputs if c not in data.source.columns]
    if missing:
        raise CandidateError(f"candidate '{candidate.name}': unknown input column(s) {missing}; "
                             f"physical columns: {list(data.source.columns)}")
    baseline = [name for name in candidate.theta if name in data.theta_names]
    if baseline:  # data.variant() would let the variant's bounds replace the baseline's
        raise CandidateError(f"candidate '{candidate.name}': theta '{baseline[0]}' is the baseline's, which keeps "
                             "its bounds in every variant; give the variant's extra parameters only")
    try:
        return data.variant(candidate.inputs, candidate.theta)
    except DataError as err:
        raise CandidateError(f"candidate '{candidate.name}': {err}") from None


def check_candidate_data(data, candidates: list[Candidate]) -> dict:
    """Each candidate against the physical data, before anything compiles
    (the config reader and `stancal gap` both): a name used once, a formula
    that evaluates, a variant's inputs and theta. Returns each variant's
    data by name (variant_data), which `stancal gap` plans each variant's
    Stan program on before checking it with stanc."""
    names = [c.name for c in candidates]
    repeated = sorted({n for n in names if names.count(n) > 1})
    if repeated:
        raise CandidateError(f"candidate name(s) {repeated} used twice")
    variants = {}
    for c in candidates:
        if c.kind == "variant":
            variants[c.name] = variant_data(data, c)
            continue
        try:
            build_mean_terms(c.formula, data.source)
        except FormulaError as err:
            raise CandidateError(f"candidate '{c.name}': {err}") from None
    return variants


def check_adds_terms(data, candidates: list[Candidate], baseline_formula: str | None) -> None:
    """`stancal gap` only: a formula candidate must widen the mean the
    baseline fits (its ``baseline_formula`` and a constant), else its fit
    is the baseline's again. Judged on the terms as fitted (with_baseline_terms),
    by the rank of their columns, so a renamed or recoded copy (``t:humidity``
    beside ``humidity*t``, ``operator`` beside ``C(operator)``) counts as no term.
    A config may keep such a candidate for a plain calibration."""
    if baseline_formula is None:  # every formula has a term beside the constant (build_mean_terms)
        return
    try:
        baseline = _rank(baseline_formula, data.source)
    except FormulaError:  # the plan names the [model]'s own error
        return
    for c in (c for c in candidates if c.kind == "formula"):
        if _rank(c.with_baseline_terms(baseline_formula), data.source) <= baseline:
            raise CandidateError(f"candidate '{c.name}': formula {c.formula!r} adds no term to [model] mean_formula "
                                 f"{baseline_formula!r}, so its fit would be the baseline's again")


def _rank(formula: str, physical) -> int:
    """How many independent columns the mean has: the formula's terms and a constant."""
    return int(np.linalg.matrix_rank(build_mean_terms(formula, physical, intercept=True).h))
