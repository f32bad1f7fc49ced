"""The sampler's options, defined once: their defaults, their limits, their
help text. calibrate() and every command that makes many fits check them
here before anything is compiled, and the command line makes its flags
from this definition, so every command takes the same ones."""

from __future__ import annotations

import math
import numbers
from dataclasses import asdict, dataclass, field, fields
from typing import Any

from stancal.problem import advice

MAX_SEED = 2**31 - 1  # Stan's seeds are unsigned 32-bit; PyStan's random_seed is a C int


def _option(default: Any, kind: type, help: str, *, minimum: float | None = None,
            below: float | None = None, above: float | None = None) -> Any:
    """A field with its command-line type, help text and limits: ``minimum``
    inclusive, ``above`` and ``below`` exclusive."""
    return field(default=default, metadata={"type": kind, "help": help, "minimum": minimum,
                                            "above": above, "below": below})


@dataclass(frozen=True)
class SamplerOptions:
    """NUTS's settings of one fit (Stan's names: num_warmup, num_samples, delta, max_depth)."""

    chains: int = _option(4, int, "Markov chains per fit, run side by side", minimum=1)
    warmup: int = _option(1000, int, "warmup (adaptation) iterations per chain; Stan adapts the step "
                                     "size and metric during warmup, so it needs at least one", minimum=1)
    draws: int = _option(1000, int, "posterior draws kept per chain, after warmup", minimum=1)
    seed: int | None = _option(None, int, f"random seed (0 to {MAX_SEED}); each fit derives its own from "
                                          "it; default: a fresh one each run", minimum=0)
    adapt_delta: float = _option(0.9, float, "the sampler's target acceptance rate, between 0 and 1; raise "
                                             "it (0.95, 0.99) when transitions diverge", above=0, below=1)
    max_treedepth: int = _option(10, int, "the largest tree depth of a NUTS transition (at most 2^depth "
                                          "leapfrog steps); raise it when transitions hit it", minimum=1)

    def __post_init__(self) -> None:
        for f in fields(self):
            _check(f.name, getattr(self, f.name), f.metadata)

    @classmethod
    def from_keywords(cls, keywords: dict[str, Any], **defaults: Any) -> SamplerOptions:
        """The options among ``keywords`` (others are left alone), over ``defaults``."""
        return cls(**{**defaults, **{k: v for k, v in keywords.items() if k in NAMES}})

    def keywords(self) -> dict[str, Any]:
        """As keyword arguments of calibrate() and a backend's sample()."""
        return asdict(self)


def _check(name: str, value: Any, limits: Any) -> None:
    """One option against its type and limits: a one-line error naming it as the caller spells it."""
    if value is None and name == "seed":
        return
    kind = limits["type"]
    whole = isinstance(value, numbers.Integral) and not isinstance(value, bool)
    if kind is int and not whole:
        raise ValueError(f"{advice.option(name)} must be a whole number; got {value!r}")
    if kind is float and not (isinstance(value, numbers.Real) and not isinstance(value, bool)
                              and math.isfinite(value)):
        raise ValueError(f"{advice.option(name)} must be a number; got {value!r}")
    low, above, below = limits["minimum"], limits["above"], limits["below"]
    if low is not None and value < low:
        raise ValueError(f"{advice.option(name)} must be at least {low}; got {value}")
    if above is not None and below is not None and not above < value < below:
        raise ValueError(f"{advice.option(name)} must lie strictly between {above} and {below}; got {value}")
    if name == "seed" and value > MAX_SEED:
        raise ValueError(f"{advice.option(name)} must be at most {MAX_SEED}; got {value}")


NAMES = tuple(f.name for f in fields(SamplerOptions))
