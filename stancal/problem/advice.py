"""How a message names what its reader can change: the Python keyword
(``adapt_delta=0.95``) for a user of the API, the flag (``--adapt-delta
0.95``), the config key or the report's file for a user of the command
line. Every message that gives advice spells it through here, so that the
advice fits whoever reads it; the command line says it is the reader once
(``spoken_to(CLI)``), and the fit runner carries the reader to the
processes that run the fits."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

PYTHON = "python"
CLI = "cli"
AUDIENCES = (PYTHON, CLI)

_audience = PYTHON  # per process: the command line sets it first thing

# where the command line writes what a Python user finds on the result
_CLI_PLACES = {
    "modes": "\"modes\" in summary.json (report.md lists them when there are several)",
    "summary by mode": "summary.csv (one block per mode)",
}
_PYTHON_PLACES = {
    "modes": "result.modes",
    "summary by mode": "result.summary()",
}


def set_audience(audience: str) -> None:
    """Who reads stancal's messages in this process: PYTHON or CLI."""
    global _audience
    if audience not in AUDIENCES:
        raise ValueError(f"audience must be one of {', '.join(AUDIENCES)}; got {audience!r}")
    _audience = audience


def audience() -> str:
    return _audience


@contextlib.contextmanager
def spoken_to(reader: str) -> Iterator[None]:
    """Messages for ``reader`` within the block (the command line's run, a fit on a worker)."""
    before = _audience
    set_audience(reader)
    try:
        yield
    finally:
        set_audience(before)


def option(name: str, value: object = None) -> str:
    """A sampling or command option as the reader writes it: ``draws`` or
    ``--draws``; with a value, ``adapt_delta=0.95`` or ``--adapt-delta 0.95``."""
    if _audience == CLI:
        flag = "--" + name.replace("_", "-")
        return flag if value is None else f"{flag} {value}"
    return name if value is None else f"{name}={value!r}"


def options(**values: object) -> str:
    """Several options with values: ``--warmup 2000 --draws 2000`` or ``warmup=2000, draws=2000``."""
    return (" " if _audience == CLI else ", ").join(option(name, value) for name, value in values.items())


def config_key(table: str, key: str, value: object) -> str:
    """A model option: a keyword of calibrate() in Python, a key of the
    config's table on the command line."""
    setting = f"{key} = {_toml(value)}"  # a keyword's value as Python and TOML both write it
    return f"{setting} in the config's [{table}] table" if _audience == CLI else setting


def place(what: str) -> str:
    """Where the reader finds a part of the result (see _PYTHON_PLACES)."""
    return (_CLI_PLACES if _audience == CLI else _PYTHON_PLACES)[what]


def _toml(value: object) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    return f'"{value}"' if isinstance(value, str) else str(value)
