"""Discrepancy analysis (issue 6): locate where the baseline model and a recording disagree, name the
physics it left out from a library of candidate terms, fit it and show the improvement.

Modules: :mod:`.data` (inputs), :mod:`.library` (candidate terms), :mod:`.fitting` (least squares),
:mod:`.model` (a fitted model), :mod:`.onestep` (one-step-ahead errors), :mod:`.locate` (where),
:mod:`.select` (which terms), :mod:`.engine` (``analyse_discrepancy``), :mod:`.figures`, :mod:`.prove`.
No rclpy, no vibro_fit.
"""

from .engine import DiscrepancyRun, analyse_discrepancy, run_discrepancy
from .library import EFFECTS, UNEXPLAINED, catalogue

__all__ = ["DiscrepancyRun", "EFFECTS", "UNEXPLAINED", "analyse_discrepancy", "catalogue", "run_discrepancy"]
