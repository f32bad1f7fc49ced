"""stancal: Bayesian calibration of computer models with Stan."""

import logging

from .calibrate import calibrate
from .data import CalibrationData, DataError, InputRangeWarning
from .diagnostics import SamplerWarning
from .models import MODELS, Kernel, Method
from .modes import MultimodalWarning
from .result import CalibrationResult
from .stan_source import StanProgramError

logging.getLogger("stancal").addHandler(logging.NullHandler())

load_result = CalibrationResult.load

__all__ = [
    "CalibrationData", "CalibrationResult", "DataError", "InputRangeWarning", "Kernel",
    "MODELS", "Method", "MultimodalWarning", "SamplerWarning", "StanProgramError",
    "calibrate", "load_result",
]
__version__ = "0.1.0"
