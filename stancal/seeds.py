"""Seeds: one per command, drawn when the user gives none, so that every
fit of the command can be rerun exactly."""

from __future__ import annotations

import numpy as np

MAX_SEED = 2**31 - 1  # Stan's seeds are unsigned 32-bit; PyStan's random_seed is a C int


def command_seed(seed: int | None) -> int:
    """The user's seed, or a fresh one."""
    return int(np.random.default_rng().integers(MAX_SEED)) if seed is None else int(seed)
