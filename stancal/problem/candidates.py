"""Candidate unmodelled effects for the gap diagnosis: a formula of mean
terms over the physical columns, or a variant simulator written in Stan."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path


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

    def __post_init__(self) -> None:
        if (self.formula is None) == (self.stan is None):
            raise CandidateError(f"candidate '{self.name}': give a formula or a Stan simulator, not both")
        if self.stan is not None and not self.inputs:
            raise CandidateError(f"candidate '{self.name}': a simulator variant needs its 'inputs' columns")
