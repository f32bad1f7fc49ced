"""Initial values spread over the theta box, so chains can find separate modes."""

from __future__ import annotations

import numpy as np


def spread_theta_inits(chains: int, n_theta: int, rng: np.random.Generator,
                       margin: float = 0.03) -> list[dict[str, list[float]]]:
    """A Latin hypercube over [margin, 1 - margin]^n_theta for theta_unit:
    each chain starts in its own stratum of every parameter. Other parameters
    get Stan's random inits."""
    strata = np.column_stack([rng.permutation(chains) for _ in range(n_theta)])
    unit = (strata + rng.uniform(size=(chains, n_theta))) / chains
    unit = margin + (1 - 2 * margin) * unit
    return [{"theta_unit": row.tolist()} for row in unit]


def theta_unit_init(values: dict[str, float], bounds: dict[str, tuple[float, float]],
                    rng: np.random.Generator, margin: float = 0.25) -> dict[str, list[float]]:
    """theta_unit at the natural ``values`` given (clipped into the box), in
    the order of ``bounds``; a parameter without a value starts at random in
    the middle of its range, [margin, 1 - margin]."""
    unit = [float(np.clip((values[name] - lo) / (hi - lo), 1e-3, 1 - 1e-3)) if name in values
            else float(rng.uniform(margin, 1 - margin)) for name, (lo, hi) in bounds.items()]
    return {"theta_unit": unit}
