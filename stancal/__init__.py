"""stancal: Bayesian calibration of computer models with Stan."""

import logging

from .calibrate import calibrate
from .data import CalibrationData, DataError, InputRangeWarning
from .diagnostics import SamplerWarning
from .gap import Candidate, CandidateError, GapWarning, diagnose_gap
from .gap_report import write_gap_report
from .mean_terms import FormulaError
from .models import MODELS, Kernel, Method
from .modes import MultimodalWarning
from .result import CalibrationResult
from .stan_source import StanProgramError

logging.getLogger("stancal").addHandler(logging.NullHandler())

load_result = CalibrationResult.load

__all__ = [
    "CalibrationData", "CalibrationResult", "Candidate", "CandidateError", "DataError",
    "FormulaError", "GapWarning", "InputRangeWarning", "Kernel", "MODELS", "Method",
    "MultimodalWarning", "SamplerWarning", "StanProgramError", "calibrate", "diagnose_gap",
    "load_result", "write_gap_report",
]
__version__ = "0.1.0"
