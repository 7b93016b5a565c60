"""Synthetic rig: complete recordings (rig.yaml, frames/, accel.csv) with a truth file beside.

``synthesize(out_dir, SynthConfig(...)) -> truth dict``; see :mod:`.scenario` for the
options and effects, :mod:`.trajectory` (physics), :mod:`.render` (images),
:mod:`.accel` (50 kHz signals) and :mod:`.write` (files).
"""

from .scenario import DEFAULT_ACCEL_MS2, EFFECT_NAMES, EFFECTS, SynthConfig, SynthError, parse_effect_args
from .write import synthesize, truth_path

__all__ = ["DEFAULT_ACCEL_MS2", "EFFECT_NAMES", "EFFECTS", "SynthConfig", "SynthError",
           "parse_effect_args", "synthesize", "truth_path"]
