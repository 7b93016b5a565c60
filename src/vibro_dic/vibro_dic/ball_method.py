"""How the ball is tracked when rig.yaml does not say: DIC subsets on a speckled ball, or its outline.

rig.yaml ``dic.ball_method`` names it (``mesh`` or ``outline``, kept as named). When the key is absent
(:attr:`vibro_io.rig.DicConfig.ball_method_named` False, e.g. a rig.yaml written by hand), the texture of frame
0's ball ROI decides, the same way for every path that tracks a recording (``vibro analyze``, chunked DIC, the
graph's dic_tracker), since it depends on frame 0 and rig.yaml alone:

- the ball ROI's DIC subsets are assessed against the noise of frame 0 (:func:`vibro_dic.texture.assess_body`,
  noise :func:`vibro_dic.texture.noise_from_image` floored at the quantization noise);
- when at least :data:`MIN_UNTEXTURED_FRACTION` of them have too little texture to track (a plain ball: no
  speckle) **and** the outline check (:func:`vibro_dic.outline.assess_outline`) accepts a round, contrasted
  outline in that ROI, the ball is tracked by its outline;
- otherwise (a speckled ball, or no clean outline to fall back on) by the DIC mesh, as before.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from vibro_io.rig import DicConfig
from vibro_model.errors import RecordingError

from .outline import assess_outline
from .texture import DEFAULT_MAX_SUBSET_SIGMA_PX, assess_body, floor_noise, noise_from_image, pixel_depth

#: the share of the ball ROI's subsets without usable texture from which a ball with a clean outline is plain
MIN_UNTEXTURED_FRACTION = 0.1


@dataclass(frozen=True)
class BallMethodChoice:
    """The ball's tracking method (``mesh`` or ``outline``), where it came from (``source``: ``rig.yaml`` or
    ``texture check``) and why (``reason``), and the DIC configuration that tracks it (``dic``)."""

    method: str
    source: str
    reason: str
    dic: DicConfig

    def to_dict(self) -> dict:
        """The results.json ``dic_quality`` keys: ``ball_method``, ``ball_method_source``, ``ball_method_reason``."""
        return {"ball_method": self.method, "ball_method_source": self.source, "ball_method_reason": self.reason}

    def describe(self) -> str:
        """One line: the method and why."""
        return f"dic.ball_method {self.method} ({self.source}: {self.reason})"


def choose_ball_method(reference_image: np.ndarray, dic_config: DicConfig, *,
                       max_subset_sigma_px: float = DEFAULT_MAX_SUBSET_SIGMA_PX) -> tuple[str, str]:
    """(method, reason): how the ball of ``reference_image`` (frame 0, 2-D) is tracked (module doc). The method
    rig.yaml names (``dic_config.ball_method_named``) is kept; else the texture of the ball ROI chooses."""
    if dic_config.ball_method_named:
        return dic_config.ball_method, "named in rig.yaml"
    ref = np.asarray(reference_image)
    try:
        estimate = floor_noise(noise_from_image(ref), pixel_depth(ref))
    except RecordingError as exc:
        return "mesh", f"no noise estimate of frame 0 to judge the ball's texture ({exc}): the default"
    noise = estimate.sigma_gray
    mesh = replace(dic_config, ball_method="mesh")
    body = assess_body("ball", ref, mesh, estimate, max_subset_sigma_px=max_subset_sigma_px)
    n = len(body.points)
    flat = n - body.n_usable
    if n == 0 or flat < MIN_UNTEXTURED_FRACTION * n:
        return "mesh", (f"the ball is speckled: {body.n_usable} of {n} DIC subsets of dic.ball_roi hold texture "
                        f"against frame 0's noise of {noise:.3g} gray levels")
    outline = assess_outline("ball", ref, dic_config.ball_roi, noise)
    if outline.refused:
        return "mesh", (f"{flat} of {n} DIC subsets of dic.ball_roi have too little texture, but the ball has no "
                        f"clean outline to track instead ({outline.problem()}): the DIC mesh, as the default")
    return "outline", (f"the ball is plain: {flat} of {n} DIC subsets of dic.ball_roi have too little texture "
                       f"against frame 0's noise of {noise:.3g} gray levels, and its outline is clean "
                       f"({outline.describe()}); name dic.ball_method in rig.yaml to choose yourself")


def resolve_ball_method(reference_image: np.ndarray, dic_config: DicConfig, *,
                        max_subset_sigma_px: float = DEFAULT_MAX_SUBSET_SIGMA_PX) -> BallMethodChoice:
    """The :class:`BallMethodChoice` of :func:`choose_ball_method`, with ``dic_config`` set to track by it."""
    method, reason = choose_ball_method(reference_image, dic_config, max_subset_sigma_px=max_subset_sigma_px)
    source = "rig.yaml" if dic_config.ball_method_named else "texture check"
    dic = dic_config if method == dic_config.ball_method else replace(dic_config, ball_method=method)
    return BallMethodChoice(method=method, source=source, reason=reason, dic=dic)

