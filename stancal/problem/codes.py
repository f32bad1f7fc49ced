"""Integer switches that the Stan programs declare in their data blocks,
mirrored once here (tests/test_stan_source.py reads the programs' own
declarations and checks that they agree)."""

from __future__ import annotations

from enum import IntEnum


class Kernel(IntEnum):
    """``kernel_id`` in the Stan programs (see functions/gp_kernels.stan)."""

    SE = 1
    MATERN52 = 2


class Likelihood(IntEnum):
    """``likelihood_id`` in the latent programs (functions/observation_model.stan)."""

    GAUSSIAN = 1
    POISSON = 2
    NEGBINOMIAL = 3
    BINOMIAL = 4


class Censoring(IntEnum):
    """``censoring`` codes per observation (functions/observation_model.stan)."""

    OBSERVED = 0
    LEFT = 1  # y <= upper
    RIGHT = 2  # y >= lower
    INTERVAL = 3  # lower <= y <= upper


# ``delta_centred`` in the latent programs: how the discrepancy GP is sampled (functions/latent_gp.stan;
# 2, partially non-centred, only in koh_latent.stan: functions/latent_partial.stan)
DISCREPANCY_PARAMETRIZATION_CODES = {"non_centred": 0, "centred": 1, "partial": 2}

# ``noise_mode`` in the vector programs (functions/vector_noise.stan)
NOISE_MODES = {"known": 0, "one": 1, "per_experiment": 2}


class Noise(IntEnum):
    """``noise_id`` in the exact Gaussian programs (functions/noise.stan):
    the measurement noise model of a scalar output ([model] noise)."""

    IID = 1
    PER_SOURCE = 2
    STUDENT_T = 3
    HETEROSCEDASTIC = 4
