"""Seeds: one per command, drawn when the user gives none, so that every
fit of the command can be rerun exactly."""

from __future__ import annotations

import hashlib

import numpy as np

from stancal.problem.sampling import MAX_SEED

__all__ = ["MAX_SEED", "command_seed", "fit_seed"]


def command_seed(seed: int | None) -> int:
    """The user's seed, or a fresh one."""
    return int(np.random.default_rng().integers(MAX_SEED)) if seed is None else int(seed)


def fit_seed(command: int, name: str) -> int:
    """One fit's seed, from its command's seed and the fit's name: the same
    whatever runs the fits (this process, a local cluster, a remote one)
    and in whatever order they finish."""
    digest = hashlib.sha256(f"{command}\0{name}".encode()).digest()
    return int.from_bytes(digest[:4], "little") % MAX_SEED
