"""One line per discrepancy finding, the same in ``vibro analyze``, ``vibro results`` and ``vibro graph``.

``finding: coulomb_friction force_n = 0.0001502 +- 7.3e-08; D 0.379 % -> 0.00599 %``: the effect, its
main (first) parameter with its 1-sigma where the analysis gives one, and the deviation D before and
after the effect is modelled.
"""

from __future__ import annotations

import math
from typing import Any, Iterable, Mapping


def _value(value: float, sigma: float | None) -> str:
    if sigma is None or not math.isfinite(sigma) or sigma <= 0:
        return f"{value:.4g}"
    return f"{value:.4g} +- {sigma:.2g}"


def finding_line(effect: str, parameters: Mapping[str, float], sigmas: Mapping[str, float] | None,
                 deviation_before: float, deviation_after: float) -> str:
    """``finding: <effect> <name> = <value> +- <sigma>; D <before> % -> <after> %`` (D as percentages)."""
    main = ""
    if parameters:
        name, value = next(iter(parameters.items()))
        main = f" {name} = {_value(float(value), (sigmas or {}).get(name))}"
    return f"finding: {effect}{main}; D {100 * deviation_before:.3g} % -> {100 * deviation_after:.3g} %"


def findings_lines(discrepancy: Mapping[str, Any] | None) -> list[str]:
    """The lines of results.json's ``discrepancy`` section (``findings: none`` when there are none)."""
    if not discrepancy:
        return ["findings: no discrepancy analysis in these results"]
    findings: Iterable[Mapping[str, Any]] = discrepancy.get("findings") or []
    lines = [finding_line(f["effect"], f.get("parameters") or {}, f.get("parameters_std"),
                          f["deviation_before"], f["deviation_after"]) for f in findings]
    return lines or ["findings: none (the model explains the recording within its noise)"]
