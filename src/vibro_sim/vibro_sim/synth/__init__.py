"""Synthetic rig: complete recordings (rig.yaml, frames/, accel.csv) with a truth file beside.

``synthesize(out_dir, SynthConfig(...)) -> truth dict``; see :mod:`.scenario` for the
options and effects, :mod:`.trajectory` (physics), :mod:`.render` (images),
:mod:`.accel` (50 kHz signals) and :mod:`.write` (files).
"""

from .scenario import DEFAULT_ACCEL_MPS2, EFFECT_NAMES, EFFECTS, SynthConfig, SynthError, parse_effect_args


def __getattr__(name: str):
    """``synthesize``/``truth_path`` load :mod:`.write` (renderer, simulator: scipy) on first use, so that
    ``vibro --help`` and the other subcommands do not pay for it at start-up."""
    if name in ("synthesize", "truth_path"):
        from . import write

        return getattr(write, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = ["DEFAULT_ACCEL_MPS2", "EFFECT_NAMES", "EFFECTS", "SynthConfig", "SynthError",
           "parse_effect_args", "synthesize", "truth_path"]
