"""The DIC's sub-pixel methods by name (:mod:`vibro_dic.tracker`), importable without the tracker and its compiled
kernels (the ``vibro`` command's parsers name them as choices)."""

#: "icgn" (inverse-compositional Gauss-Newton, the default) or "parabolic" (the baseline)
METHODS = ("icgn", "parabolic")
