"""Discrepancy analysis: locate where the baseline model and a recording disagree, name the
physics it left out from a library of candidate terms, fit it and show the improvement.

An estimator split like PySINDy's: :mod:`.library` (candidate terms, :class:`CandidateLibrary`) x
:mod:`.select` (which terms, :class:`StagewiseSelector`) -> :mod:`.engine` (:class:`DiscrepancyEstimator`,
``run_discrepancy``) -> a fitted model (:mod:`.model`, :class:`DiscrepancyRun` with typed findings). Around
them: :mod:`.data` (the measurement from the domain model), :mod:`.fitting` (least squares), :mod:`.runs`
(D and D_r), :mod:`.onestep` (one-step-ahead errors), :mod:`.locate` (where), :mod:`.systematic`
(out-of-catalogue mismatches), :mod:`.tone` (a located structure tone, modelled), :mod:`.shape_model` (a
located position force or COR parity, modelled), :mod:`.reidentify`
(impacts re-measured under the final model), :mod:`.figures`. No rclpy, no vibro_fit.
"""

from vibro_discrepancy.engine import DiscrepancyEstimator, DiscrepancyRun, analyse_discrepancy, run_discrepancy
from vibro_discrepancy.library import EFFECTS, UNEXPLAINED, CandidateLibrary, catalogue
from vibro_discrepancy.select import StagewiseSelector

__all__ = ["CandidateLibrary", "DiscrepancyEstimator", "DiscrepancyRun", "EFFECTS", "StagewiseSelector", "UNEXPLAINED",
           "analyse_discrepancy", "catalogue", "run_discrepancy"]
