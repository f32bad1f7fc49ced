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
