"""One row per campaign run (from its results.json and rig.yaml), and the runs that disagree with the rest.

Disagreement rule (per plate, top and bottom): runs are grouped by their nominal excitation (rig.yaml's
``excitation.frequency_hz`` and ``excitation.acceleration_mps2``, when given) and the rig's orientation
(``setup.axis_tilt_deg``: a run at another orientation is another experiment, not a disagreeing one); in a group
of at least
:data:`MIN_GROUP` runs with a COR on that plate, a run's robust z-score is
``z = (mean COR - median of the group) / scale`` with ``scale = max(1.4826 x MAD, median of the runs'
standard errors sigma/sqrt(n))`` (MAD: median absolute deviation from the group median; the floor keeps runs
that agree better than their own noise from flagging a difference within it). ``|z| > Z_FLAG`` (3.5, as
Iglewicz and Hoaglin recommend for modified z-scores) flags the run, naming plate, z and the group median.

Orientation study (the paper's Fig. 11: one test repeated vertical, tilted and horizontal):
:func:`orientation_groups` pools the impacts' CORs of the runs at each ``setup.axis_tilt_deg``, per plate: mean,
sample std and the 95 % confidence interval of the mean, mean +- t(0.975, n - 1) std / sqrt(n) (Student t; the
impacts taken as independent draws of the contact's COR).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from vibro_io.rig import load_rig
from vibro_model.errors import RecordingError

PLATES = ("top", "bottom")
MIN_GROUP = 3
Z_FLAG = 3.5


def _num(value) -> float | None:
    """A finite float, else None (JSON has no NaN)."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        return None
    return v if math.isfinite(v) else None


def run_summary(record: dict, run_dir: Path) -> dict:
    """The campaign row of a run: ``record`` (from :func:`.task.analyze_run`, or a resumed run's) with the
    excitation (rig.yaml), the identified structure motion, impacts, COR per plate and the findings read
    from ``run_dir/results.json``. A run whose results cannot be read becomes failed, saying why."""
    row = dict(record)
    row.update(excitation={"frequency_hz": None, "acceleration_mps2": None}, setup={"axis_tilt_deg": None},
               structure={}, n_impacts=None,
               cor={p: {"mean": None, "std": None, "n": 0} for p in PLATES}, impacts=[], findings=[],
               flags=[], outputs=None)
    try:
        rig = load_rig(Path(record["recording"]) / "rig.yaml")
        row["excitation"] = {"frequency_hz": rig.excitation.frequency_hz,
                             "acceleration_mps2": rig.excitation.acceleration_mps2}
        row["setup"] = {"axis_tilt_deg": rig.setup.axis_tilt_deg}
    except RecordingError:
        pass  # a failed run's rig.yaml may be what failed; its reason says so
    if row["status"] != "ok":
        return row
    results_path = run_dir / "results.json"
    try:
        doc = json.loads(results_path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        row.update(status="failed", reason=f"{results_path}: cannot read the run's results ({exc})")
        return row
    s = doc.get("structure") or {}
    row["structure"] = {"amplitude_mm": _num(s.get("amplitude_mm")), "frequency_hz": _num(s.get("frequency_hz"))}
    impacts = doc.get("impacts") or []
    row["n_impacts"] = len(impacts)
    row["impacts"] = [{"plate": i.get("plate"), "cor": _num(i.get("cor")),
                       "speed_mps": _num(abs(i["v_ball_before"] - i["v_structure"]))
                       if _num(i.get("v_ball_before")) is not None and _num(i.get("v_structure")) is not None
                       else None} for i in impacts]
    for plate in PLATES:
        c = (doc.get("cor_summary") or {}).get(plate) or {}
        row["cor"][plate] = {"mean": _num(c.get("mean")), "std": _num(c.get("std")), "n": int(c.get("n") or 0)}
    for f in (doc.get("discrepancy") or {}).get("findings") or []:
        std = f.get("parameters_std") or {}
        row["findings"].append({
            "effect": f.get("effect"),
            "parameters": {k: {"value": _num(v), "std": _num(std.get(k))}
                           for k, v in (f.get("parameters") or {}).items()},
            "where": " ".join(str(f.get("where", "")).split()),
        })
    row["outputs"] = str(run_dir)
    return row


def excitation_key(row: dict) -> tuple:
    """The group of a run: its nominal (frequency Hz, acceleration m/s^2 or None), rounded to 6 digits."""
    e = row["excitation"]
    return tuple(None if e.get(k) is None else float(f"{e[k]:.6g}") for k in ("frequency_hz", "acceleration_mps2"))


def excitation_label(key: tuple) -> str:
    f, a = key[:2]
    tilt = key[2] if len(key) > 2 else None
    return (("? Hz" if f is None else f"{f:g} Hz") + ("" if a is None else f", {a:g} m/s²")
            + ("" if not tilt else f", axis {tilt:g}°"))


def orientation_key(row: dict) -> float | None:
    """The run's rig orientation, rig.yaml ``setup.axis_tilt_deg`` (deg from vertical; None: rig.yaml unread)."""
    tilt = (row.get("setup") or {}).get("axis_tilt_deg")
    return None if tilt is None else float(f"{float(tilt):.6g}")


def orientation_groups(rows: list[dict]) -> list[dict]:
    """The analysed runs grouped by orientation (``setup.axis_tilt_deg``, ascending): per group the runs and, per
    plate, the pooled impacts' COR: n, mean, std and the 95 % confidence interval of the mean (module doc;
    ``ci95_low``/``ci95_high`` None with fewer than 2 impacts)."""
    from scipy.stats import t as student_t

    groups: dict[float, list[dict]] = {}
    for r in rows:
        if r["status"] == "ok" and orientation_key(r) is not None:
            groups.setdefault(orientation_key(r), []).append(r)
    out = []
    for tilt in sorted(groups):
        members = groups[tilt]
        plates = {}
        for plate in PLATES:
            cors = np.array([m["cor"] for r in members for m in r["impacts"]
                             if m["plate"] == plate and m["cor"] is not None], float)
            n = int(cors.size)
            mean = float(cors.mean()) if n else None
            std = float(cors.std(ddof=1)) if n >= 2 else None
            half = float(student_t.ppf(0.975, n - 1) * std / math.sqrt(n)) if n >= 2 else None
            plates[plate] = {"n": n, "mean": mean, "std": std, "ci95_half_width": half,
                             "ci95_low": None if half is None else mean - half,
                             "ci95_high": None if half is None else mean + half}
        out.append({"axis_tilt_deg": tilt, "runs": [r["name"] for r in members], "cor": plates})
    return out


def robust_z(values: np.ndarray, std_errors: np.ndarray) -> tuple[np.ndarray, float, float]:
    """(z per value, group median, scale) of the module doc's rule."""
    med = float(np.median(values))
    mad = float(np.median(np.abs(values - med)))
    scale = max(1.4826 * mad, float(np.median(std_errors)) if std_errors.size else 0.0)
    if scale <= 0:
        return np.zeros_like(values), med, scale
    return (values - med) / scale, med, scale


def flag_disagreeing(rows: list[dict]) -> None:
    """Set each ok row's ``flags`` (list of {plate, z, group_median, group_n, excitation}) by the rule of the
    module doc; rows of groups too small get none."""
    groups: dict[tuple, list[dict]] = {}
    for row in rows:
        if row["status"] == "ok":
            groups.setdefault(excitation_key(row) + (orientation_key(row),), []).append(row)
    for key, members in groups.items():
        for plate in PLATES:
            have = [r for r in members if r["cor"][plate]["mean"] is not None and r["cor"][plate]["n"] > 0]
            if len(have) < MIN_GROUP:
                continue
            values = np.array([r["cor"][plate]["mean"] for r in have])
            ses = np.array([(r["cor"][plate]["std"] or 0.0) / math.sqrt(r["cor"][plate]["n"]) for r in have])
            z, med, _ = robust_z(values, ses)
            for r, zi in zip(have, z):
                if abs(zi) > Z_FLAG:
                    r["flags"].append({"plate": plate, "z": float(zi), "group_median": med, "group_n": len(have),
                                       "excitation": excitation_label(key)})
