"""The ball's in-plane spin per flight from the DIC rotation, and whether the COR scatter follows it.

Input: the track's ``ball_rot_rad`` (rad since frame 0, + counter-clockwise as the camera sees the
image; :mod:`vibro_dic.rotation`) and ``ball_rot_std_rad``, the fitted flights and the impacts.

- Spin of a flight: least-squares line theta = theta0 + omega t over the flight's frames (first to
  last fitted frame); omega in rad/s. Its 1-sigma is sigma_theta / sqrt(sum (t - mean t)^2) with
  sigma_theta per frame the larger of the pooled residual RMS of all flights' lines and the median
  noise the tracker expects from the subsets' residuals about the rigid fit (``ball_rot_std_rad``
  ~ subset displacement noise / (mesh radius x sqrt(points))). A constant angle offset (the
  reference frame's own noise, ~sigma_theta from frame 1 on) goes into each line's intercept.
- Spin change at an impact: omega after - omega before (flights on both sides), sigma in quadrature.
- Is there spin at all: chi2 = sum (omega_k / sigma_k)^2 over the flights (k dof); no spin is
  claimed unless chi2's p-value < 0.01.
- Correlation: Spearman rank correlation of the COR residual (the impact's COR minus its plate's
  mean) with (1) the spin change, (2) its magnitude and (3) the mean spin magnitude of the two
  flights, each at alpha = 0.01 / 3 (Bonferroni: at most 1 % false alarms for the three together).
"""

from __future__ import annotations

import math
from typing import Any, Iterable, Sequence

import numpy as np

from vibro_model.tail_probability import chi2_sf

MIN_FLIGHT_FRAMES = 5
MIN_IMPACTS_FOR_CORRELATION = 6
SPIN_ALPHA = 0.01
CORRELATION_ALPHA = 0.01
TESTS = ("spin_change", "abs_spin_change", "abs_spin")
#: DIC follows a rotation from frame 0 up to about this angle (translation-only 31 px subsets)
TRACKABLE_ANGLE_RAD = 0.05


def _line(t: np.ndarray, y: np.ndarray) -> tuple[float, float, float]:
    """(slope, residual sum of squares, sum (t - mean)^2) of a least-squares line."""
    tc = t - t.mean()
    sxx = float(tc @ tc)
    slope = float(tc @ (y - y.mean())) / sxx
    res = y - y.mean() - slope * tc
    return slope, float(res @ res), sxx


def flight_spins(t_s: np.ndarray, rot_rad: np.ndarray, rot_std_rad: np.ndarray, flights: Iterable) -> dict:
    """Per-flight spin (see module doc). ``flights``: objects with ``index``, ``t_first_frame_s``,
    ``t_last_frame_s`` (s) and ``free``. Returns the noise figures and one row per flight fitted."""
    ok = np.isfinite(rot_rad) & np.isfinite(t_s)
    rows, rss, dof = [], 0.0, 0
    for f in flights:
        if not getattr(f, "free", True) or f.t_first_frame_s is None or f.t_last_frame_s is None:
            continue
        m = ok & (t_s >= f.t_first_frame_s - 1e-9) & (t_s <= f.t_last_frame_s + 1e-9)
        n = int(m.sum())
        if n < MIN_FLIGHT_FRAMES:
            continue
        slope, r, sxx = _line(t_s[m], rot_rad[m])
        rows.append({"index": int(f.index), "t_start": float(t_s[m][0]), "t_end": float(t_s[m][-1]),
                     "n_frames": n, "omega_rad_s": slope, "_sxx": sxx})
        rss += r
        dof += n - 2
    expected = float(np.nanmedian(rot_std_rad[ok])) if np.any(ok & np.isfinite(rot_std_rad)) else math.nan
    measured = math.sqrt(rss / dof) if dof > 0 else math.nan
    sigma = np.nanmax([expected, measured]) if np.isfinite([expected, measured]).any() else math.nan
    for row in rows:
        row["omega_std_rad_s"] = float(sigma / math.sqrt(row.pop("_sxx")))
    return {"rows": rows, "expected_rad": expected, "measured_rad": measured, "sigma_rad": float(sigma)}


def _average_ranks(x: np.ndarray) -> np.ndarray:
    """Ranks 1..n of ``x``, ties given their average rank (scipy.stats.rankdata's "average")."""
    order = np.argsort(x, kind="mergesort")
    xs = x[order]
    edges = np.flatnonzero(np.r_[True, xs[1:] != xs[:-1], True])
    ranks = np.empty(x.size)
    ranks[order] = np.repeat((edges[:-1] + edges[1:] + 1) / 2.0, np.diff(edges))
    return ranks


def _spearman(x: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    """Spearman's rho of ``x`` and ``y`` and its two-sided p-value from Student's t with n - 2 dof, the
    numbers scipy.stats.spearmanr gives (without importing scipy.stats: ~1.5 s of CPU per process)."""
    from scipy.special import stdtr

    rx, ry = _average_ranks(np.asarray(x, float)), _average_ranks(np.asarray(y, float))
    dx, dy = rx - rx.mean(), ry - ry.mean()
    den = math.sqrt(float(dx @ dx) * float(dy @ dy))
    if den == 0.0:
        return math.nan, math.nan  # a constant sample: no correlation defined
    rho = max(-1.0, min(1.0, float(dx @ dy) / den))
    dof = x.size - 2
    if abs(rho) == 1.0:
        return rho, 0.0
    t = rho * math.sqrt(dof / ((1.0 - rho) * (1.0 + rho)))
    return rho, float(2.0 * stdtr(dof, -abs(t)))


def _cor_residuals(impacts: Sequence) -> np.ndarray:
    """COR minus its plate's mean over ``impacts`` (those with a COR)."""
    cor = np.array([i.cor for i in impacts], dtype=float)
    plate = np.array([i.plate for i in impacts])
    out = np.empty_like(cor)
    for p in set(plate):
        m = plate == p
        out[m] = cor[m] - cor[m].mean()
    return out


def ball_spin_section(track, flights: Iterable, impacts: Iterable) -> dict[str, Any]:
    """results.json's ``ball_spin`` section (rad, rad/s, s) from a DicTrack, the flights and impacts
    (:class:`vibro_model.results.Flight`/``Impact``, final CORs)."""
    t = np.asarray(track.t_s, dtype=float)
    good = np.asarray(track.good, dtype=bool)
    rot = np.where(good, np.asarray(track.ball_rot_rad, dtype=float), np.nan)
    std = np.where(good, np.asarray(track.ball_rot_std_rad, dtype=float), np.nan)
    base = {"convention": "in-plane rotation of the ball, rad, + counter-clockwise as the camera sees the image; "
                          "omega from a line fit of the angle over each free flight",
            "method": "least-squares rigid rotation of the ball mesh's subset displacements about its centroid, "
                      "lever arms corrected for translation-only subsets (vibro_dic.rotation)"}
    if np.count_nonzero(np.isfinite(rot)) < MIN_FLIGHT_FRAMES:
        return {**base, "available": False, "spin_detected": False, "flights": [], "impacts": [],
                "correlation": None,
                "statement": "no ball rotation in the DIC track (a dic.csv written before ball_rot_rad, or a ball "
                             "mesh of fewer than 2 points): no spin reported"}
    fs = flight_spins(t, rot, std, flights)
    rows = fs["rows"]
    by_index = {r["index"]: r for r in rows}
    z2 = sum((r["omega_rad_s"] / r["omega_std_rad_s"]) ** 2 for r in rows)
    p_spin = chi2_sf(z2, len(rows)) if rows else math.nan
    detected = bool(rows) and p_spin < SPIN_ALPHA
    floor = float(np.median([r["omega_std_rad_s"] for r in rows])) if rows else math.nan
    for r in rows:
        r["significant"] = bool(abs(r["omega_rad_s"]) > 3.0 * r["omega_std_rad_s"])
    imp_rows, used = [], []
    for imp in impacts:
        a, b = by_index.get(imp.flight_before), by_index.get(imp.flight_after)
        if a is None or b is None:
            continue
        change = b["omega_rad_s"] - a["omega_rad_s"]
        imp_rows.append({"index": int(imp.index), "t": imp.t_s, "plate": imp.plate, "cor": imp.cor,
                         "omega_before_rad_s": a["omega_rad_s"], "omega_after_rad_s": b["omega_rad_s"],
                         "spin_change_rad_s": change,
                         "spin_change_std_rad_s": math.hypot(a["omega_std_rad_s"], b["omega_std_rad_s"])})
        if imp.cor is not None and math.isfinite(imp.cor):
            used.append((imp, imp_rows[-1]))
    corr = _correlation(used)
    angle_max = float(np.nanmax(np.abs(rot)))
    noise = {"angle_expected_rad": fs["expected_rad"], "angle_measured_rad": fs["measured_rad"],
             "angle_sigma_rad": fs["sigma_rad"], "omega_floor_rad_s": floor,
             "note": "per-frame angle noise: expected from the subsets' residuals about the rigid fit "
                     "(~ subset noise / (mesh radius sqrt(points))) and measured as the flights' line residuals; "
                     "omega_floor_rad_s is a flight's median 1-sigma spin"}
    section = {**base, "available": True, "spin_detected": detected, "chi2": z2, "chi2_dof": len(rows),
               "chi2_p": p_spin, "angle_max_abs_rad": angle_max, "noise": noise, "flights": rows,
               "impacts": imp_rows, "correlation": corr}
    section["statement"] = _statement(section)
    if angle_max > TRACKABLE_ANGLE_RAD:
        section["warning"] = (f"the ball turned up to {angle_max:.3f} rad from frame 0: DIC's translation-only "
                              f"subsets lose accuracy beyond ~{TRACKABLE_ANGLE_RAD} rad")
    return section


def _correlation(used: list) -> dict[str, Any]:
    n = len(used)
    out: dict[str, Any] = {"n": n, "alpha": CORRELATION_ALPHA, "alpha_per_test": CORRELATION_ALPHA / len(TESTS),
                           "cor_residual": "impact COR minus its plate's mean", "tests": {}}
    if n < MIN_IMPACTS_FOR_CORRELATION:
        out["note"] = f"{n} impacts with a COR and a spin on both sides; need {MIN_IMPACTS_FOR_CORRELATION}"
        out["significant"] = False
        return out
    r = _cor_residuals([u[0] for u in used])
    change = np.array([u[1]["spin_change_rad_s"] for u in used])
    spin = 0.5 * (np.abs([u[1]["omega_before_rad_s"] for u in used])
                  + np.abs([u[1]["omega_after_rad_s"] for u in used]))
    for name, x in zip(TESTS, (change, np.abs(change), spin)):
        rho, p = _spearman(r, x)
        out["tests"][name] = {"rho": rho, "p": p}
    best = min(out["tests"], key=lambda k: out["tests"][k]["p"])
    out["strongest"] = best
    out["significant"] = bool(out["tests"][best]["p"] < out["alpha_per_test"])
    return out


_WHAT = {"spin_change": "the spin change", "abs_spin_change": "the spin change's magnitude",
         "abs_spin": "the spin magnitude"}


def _statement(s: dict) -> str:
    c = s["correlation"]
    noise = s["noise"]
    if c.get("tests"):
        k = c["strongest"]
        t = c["tests"][k]
        nums = f"Spearman rho={t['rho']:.2f}, p={t['p']:.2g}, n={c['n']}"
    else:
        k, nums = None, c.get("note", "")
    if not s["spin_detected"]:
        return (f"no spin above the DIC noise (chi2={s['chi2']:.1f} on {s['chi2_dof']} flights, p={s['chi2_p']:.2g}; "
                f"per-frame angle noise {noise['angle_sigma_rad']:.2g} rad, a flight resolves "
                f"{noise['omega_floor_rad_s']:.2g} rad/s): no spin is claimed and the COR scatter is not "
                f"attributed to spin ({nums})")
    if k is None:
        return f"the ball spins (chi2 p={s['chi2_p']:.2g}); too few impacts to test the COR scatter against it ({nums})"
    if c["significant"]:
        return f"COR scatter correlates with {_WHAT[k]} ({nums}; alpha {c['alpha_per_test']:.2g} per test)"
    return (f"COR scatter does not correlate with spin ({nums}, the strongest of {len(TESTS)} tests; "
            f"alpha {c['alpha_per_test']:.2g} per test)")
