"""stancal: Bayesian calibration of computer models with Stan."""

import logging

from stancal.designing.loop import Design, WaveLoop, propose_experiments, propose_runs, run_waves
from stancal.designing.targets import DesignSettings
from stancal.designing.waves import HistoryMatch, history_match
from stancal.diagnosing.compare import Comparison, compare_methods
from stancal.diagnosing.gap import Candidate, CandidateError, GapWarning, diagnose_gap
from stancal.fitting.calibrate import calibrate
from stancal.fitting.confounding import ConfoundingWarning
from stancal.problem.codes import Kernel
from stancal.problem.data import CalibrationData, DataError, InputRangeWarning
from stancal.problem.mean_terms import FormulaError
from stancal.reporting.compare_report import write_comparison
from stancal.reporting.gap_report import write_gap_report
from stancal.reporting.report import write_calibration
from stancal.results.diagnostics import SamplerWarning
from stancal.results.modes import MultimodalWarning
from stancal.results.result import CalibrationResult
from stancal.stan.registry import MODELS, PROGRAMS, Program, register
from stancal.stan.source import StanProgramError

logging.getLogger("stancal").addHandler(logging.NullHandler())

load_result = CalibrationResult.load

__all__ = [
    "CalibrationData", "CalibrationResult", "Candidate", "CandidateError", "Comparison", "ConfoundingWarning",
    "DataError", "Design", "DesignSettings", "HistoryMatch", "WaveLoop", "history_match", "propose_experiments",
    "propose_runs", "run_waves",
    "FormulaError", "GapWarning", "InputRangeWarning", "Kernel", "MODELS", "PROGRAMS", "Program",
    "MultimodalWarning", "SamplerWarning", "StanProgramError", "calibrate", "diagnose_gap",
    "compare_methods", "load_result", "register", "write_calibration", "write_comparison", "write_gap_report",
]
__version__ = "0.1.0"
