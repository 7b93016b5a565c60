"""Vibro-impact models (COR and Hertz-damped contact), simulator node and a synthetic rig that writes recordings with ground truth."""
