"""Backend selection: the only place that knows which Stan interfaces exist."""

from __future__ import annotations

import os

from stancal.stan.backends.base import Draws, SampleOutput, StanBackend, StanRuntimeError, WarmStart
from stancal.stan.backends.cmdstanpy_backend import CmdStanPyBackend, cmdstan_available
from stancal.stan.backends.pystan_backend import PyStanBackend

BACKENDS = ("auto", "cmdstanpy", "pystan")


def get_backend(name: str | None = None) -> StanBackend:
    """``auto`` (default, or $STANCAL_BACKEND) picks cmdstanpy when CmdStan is
    installed, else the embedded PyStan."""
    choice = (name or os.environ.get("STANCAL_BACKEND") or "auto").lower()
    if choice not in BACKENDS:
        raise ValueError(f"backend must be one of {', '.join(BACKENDS)}; got {choice!r}")
    if choice == "auto":
        choice = "cmdstanpy" if cmdstan_available() else "pystan"
    if choice == "cmdstanpy":
        if not cmdstan_available():
            raise RuntimeError(
                "backend 'cmdstanpy' needs a CmdStan installation "
                "(cmdstanpy.cmdstan_path() failed); use backend='pystan' or install CmdStan"
            )
        return CmdStanPyBackend()
    return PyStanBackend()


__all__ = ["Draws", "SampleOutput", "StanBackend", "StanRuntimeError", "WarmStart", "get_backend", "BACKENDS"]
