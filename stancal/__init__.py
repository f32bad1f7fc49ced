"""stancal: Bayesian calibration of computer models with Stan."""

import logging

from .calibrate import calibrate
from .compare import Comparison, compare_methods, write_comparison
from .data import CalibrationData, DataError, InputRangeWarning
from .diagnostics import SamplerWarning
from .gap import Candidate, CandidateError, GapWarning, diagnose_gap
from .gap_report import write_gap_report
from .mean_terms import FormulaError
from .models import MODELS, Kernel, Method
from .modes import MultimodalWarning
from .report import write_calibration
from .result import CalibrationResult
from .stan_source import StanProgramError

logging.getLogger("stancal").addHandler(logging.NullHandler())

load_result = CalibrationResult.load

__all__ = [
    "CalibrationData", "CalibrationResult", "Candidate", "CandidateError", "Comparison", "DataError",
    "FormulaError", "GapWarning", "InputRangeWarning", "Kernel", "MODELS", "Method",
    "MultimodalWarning", "SamplerWarning", "StanProgramError", "calibrate", "diagnose_gap",
    "compare_methods", "load_result", "write_calibration", "write_comparison", "write_gap_report",
]
__version__ = "0.1.0"
