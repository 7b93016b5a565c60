"""The report's tables for a referee: the paper's Table 2 per plate with its inference (standard error, 95 %
interval of the mean, normality), and one row per impact, sortable, from results.json's ``impacts``.

The statistics are plain functions of the impacts' dicts (:func:`plate_statistics`, :func:`impact_rows`);
the HTML functions only print them. scipy.stats is imported inside :func:`plate_statistics` (start-up cost,
see tests/test_startup_imports.py).
"""

from __future__ import annotations

import html
import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from vibro_app.findings_text import effect_label, value_pm
from vibro_model.statistics import normal_check

PLATES = ("top", "bottom")

#: Shapiro-Wilk's range in scipy.stats.shapiro (below 3 undefined, above 5000 the p-value is inexact)
SHAPIRO_N = (3, 5000)

#: under Table 2: where the page says what each impact's sigma contains (vibro_app.report_methods.uncertainty_html)
SIGMA_POINTER = ('What each impact\'s sigma contains and what it does not: <a href="#uncertainty">Uncertainty of the '
                 "COR</a>.")


@dataclass(frozen=True)
class PlateStatistics:
    """One plate's CORs as Table 2 reports them, with the inference a referee asks for.

    ``n``: CORs known (finite); ``n_missing``: impacts on the plate without one. ``std`` ddof = 1;
    ``sem`` = std / sqrt(n); ``ci`` the ``confidence`` interval of the mean (Student t, n - 1 dof);
    ``qq_r`` the normal Q-Q correlation (n >= 3); ``shapiro_p`` Shapiro-Wilk's p-value (3 <= n <= 5000).
    Undefined numbers are None.
    """

    plate: str
    n: int
    n_missing: int
    mean: float | None
    std: float | None
    sem: float | None
    ci: tuple[float, float] | None
    confidence: float
    qq_r: float | None
    shapiro_p: float | None


def _cor(imp: Mapping[str, Any]) -> float:
    c = imp.get("cor")
    return math.nan if c is None else float(c)


def mean_interval(values: Sequence[float], confidence: float = 0.95) -> tuple[float, float] | None:
    """The two-sided ``confidence`` interval of the mean of ``values`` (Student t, n - 1 dof); None for n < 2."""
    from scipy import stats

    v = np.asarray(values, float)
    if v.size < 2:
        return None
    m, sem = float(v.mean()), float(v.std(ddof=1)) / math.sqrt(v.size)
    half = float(stats.t.ppf(0.5 + confidence / 2.0, v.size - 1)) * sem
    return m - half, m + half


def shapiro_p(values: Sequence[float]) -> float | None:
    """Shapiro-Wilk's p-value of ``values`` (None outside 3 <= n <= 5000, or for a constant sample)."""
    from scipy import stats

    v = np.asarray(values, float)
    if not SHAPIRO_N[0] <= v.size <= SHAPIRO_N[1] or np.ptp(v) == 0:
        return None
    return float(stats.shapiro(v).pvalue)


def plate_statistics(impacts: Iterable[Mapping[str, Any]], confidence: float = 0.95) -> dict[str, PlateStatistics]:
    """{"top": ..., "bottom": ...}: :class:`PlateStatistics` of the CORs of results.json's ``impacts``.

    Parameters
    ----------
    impacts
        results.json ``impacts`` (dicts with ``plate`` and ``cor``; a None COR counts in ``n_missing``).
    confidence
        The coverage of the interval of the mean.

    Returns
    -------
    dict
        One :class:`PlateStatistics` per plate.
    """
    impacts = list(impacts)
    out = {}
    for plate in PLATES:
        cors = np.array([_cor(i) for i in impacts if i.get("plate") == plate], float)
        v = cors[np.isfinite(cors)]
        n = int(v.size)
        std = float(v.std(ddof=1)) if n > 1 else None
        r = normal_check(v).r if n >= 3 else None
        out[plate] = PlateStatistics(
            plate=plate, n=n, n_missing=int(cors.size - n), mean=float(v.mean()) if n else None, std=std,
            sem=None if std is None else std / math.sqrt(n), ci=mean_interval(v, confidence), confidence=confidence,
            qq_r=None if r is None or not math.isfinite(r) else float(r), shapiro_p=shapiro_p(v))
    return out


def _decimals(sem: float | None, least: int = 4) -> int:
    """Decimals that show ``sem`` (a standard error or deviation) to its second significant digit, at least
    ``least``: a COR scatter of 1e-5 is not printed as 0.0000."""
    if sem is None or not math.isfinite(sem) or sem <= 0:
        return least
    return max(least, 1 - math.floor(math.log10(sem)))


def _num(v: float | None, spec: str) -> str:
    return "n/a" if v is None or not math.isfinite(v) else format(v, spec)


def table2_html(impacts: Iterable[Mapping[str, Any]], confidence: float = 0.95) -> str:
    """Table 2 per plate (n, mean, std, standard error, interval of the mean, Q-Q r, Shapiro-Wilk p) and a link to
    what each impact's sigma contains; empty without impacts."""
    stats = plate_statistics(impacts, confidence)
    if not any(s.n or s.n_missing for s in stats.values()):
        return ""
    pct = f"{100 * confidence:g} %"
    rows = []
    for s in stats.values():
        n = f"{s.n}" + (f" (+{s.n_missing} without COR)" if s.n_missing else "")
        fixed = _decimals(s.sem)   # the mean and its interval to the standard error's second digit
        ci = "n/a" if s.ci is None else f"[{s.ci[0]:.{fixed}f}, {s.ci[1]:.{fixed}f}]"
        rows.append(f'<tr data-plate="{s.plate}"><th>{s.plate}</th><td>{n}</td><td>{_num(s.mean, f".{fixed}f")}</td>'
                    f"<td>{_num(s.std, f'.{_decimals(s.std)}f')}</td><td>{_num(s.sem, f'.{fixed}f')}</td><td>{ci}</td>"
                    f"<td>{_num(s.qq_r, '.4f')}</td><td>{_num(s.shapiro_p, '.3g')}</td></tr>")
    return ('<table id="table2"><tr><th>plate</th><th>n</th><th>mean COR</th><th>std (ddof=1)</th>'
            f"<th>std. error of the mean</th><th>{pct} interval of the mean (Student t)</th>"
            "<th>normal Q-Q r</th><th>Shapiro-Wilk p</th></tr>" + "".join(rows) + "</table>"
            f"<p>{SIGMA_POINTER}</p>")


def _rel(imp: Mapping[str, Any], key: str) -> float | None:
    vb, vs = imp.get(key), imp.get("v_structure")
    return None if vb is None or vs is None else abs(float(vb) - float(vs))


def impact_flags(imp: Mapping[str, Any], creeping_plates: Iterable[str] = ()) -> list[str]:
    """What a referee should know of one impact, in words (the page names no results.json key): found in lost
    frames (``in_gap``), local structure (re-measured with the local structure velocity), re-measured (under the
    final model), its plate creeping (``creeping_plates``: the plate's velocity in Eq. 16 is the structure's plus
    the creep, results.json ``plate_motion``), no COR."""
    flags = []
    if imp.get("plate") in set(creeping_plates) and imp.get("cor") is not None:
        flags.append("plate creeps (in Eq. 16)")
    if imp.get("in_gap"):
        flags.append(f"in lost frames ({imp.get('gap_lost_frames')} lost)")
    method = imp.get("cor_method") or ""
    if method.endswith("local_structure"):
        flags.append("local structure")
    elif method and method != "paper":
        flags.append("re-measured")
    if imp.get("cor") is None:
        flags.append("no COR")
    return flags


def impact_rows(impacts: Iterable[Mapping[str, Any]], creeping_plates: Iterable[str] = ()) -> list[dict[str, Any]]:
    """One dict per impact: index, t (s), plate, relative speed in/out (m/s, |v_ball -/+ - v_structure|), cor,
    cor_std, cor_method (the identification's "paper" when absent) and flags (:func:`impact_flags`)."""
    return [{"index": imp.get("index"), "t": imp.get("t"), "plate": imp.get("plate"),
             "speed_in": _rel(imp, "v_ball_before"), "speed_out": _rel(imp, "v_ball_after"),
             "cor": imp.get("cor"), "cor_std": imp.get("cor_std"), "cor_method": imp.get("cor_method") or "paper",
             "flags": impact_flags(imp, creeping_plates)} for imp in impacts]


#: a click on a header sorts the rows by that column (numbers by data-v, text otherwise); again: reversed
SORT_JS = """<script>
document.querySelectorAll('table.sortable').forEach(function (t) {
  t.querySelectorAll('th').forEach(function (th, col) {
    th.style.cursor = 'pointer';
    th.addEventListener('click', function () {
      var body = t.tBodies[0], rows = Array.from(body.rows), dir = th.dataset.dir === 'a' ? -1 : 1;
      th.dataset.dir = dir > 0 ? 'a' : 'd';
      var key = function (r) { var c = r.cells[col], v = c.dataset.v;
        return v !== undefined ? (v === '' ? Infinity : parseFloat(v)) : c.textContent; };
      rows.sort(function (a, b) { var x = key(a), y = key(b); return (x < y ? -1 : x > y ? 1 : 0) * dir; });
      rows.forEach(function (r) { body.appendChild(r); });
    });
  });
});
</script>"""


def _cell(v: float | None, spec: str) -> str:
    ok = v is not None and math.isfinite(v)
    return f'<td data-v="{repr(float(v)) if ok else ""}">{format(v, spec) if ok else "n/a"}</td>'


def creeping_plates(results: Mapping[str, Any]) -> list[str]:
    """The plates whose creep the identification took into their CORs (results.json ``plate_motion``, applied)."""
    section = results.get("plate_motion") or {}
    return [p for p, m in section.items() if isinstance(m, Mapping) and m.get("applied") is True]


def impacts_table_html(impacts: Iterable[Mapping[str, Any]], csv_name: str = "impacts.csv",
                       moving_plates: Iterable[str] = ()) -> str:
    """The per-impact table (:func:`impact_rows`; ``moving_plates``: :func:`creeping_plates`), sortable by a click
    on a header (inline script, works offline), in a scrollable box, with a link to ``csv_name``; empty without
    impacts."""
    rows = impact_rows(impacts, moving_plates)
    if not rows:
        return ""
    e = html.escape
    body = []
    for r in rows:
        cor = ("<td data-v=\"\">n/a</td>" if r["cor"] is None else
               f'<td data-v="{r["cor"]!r}">{e(value_pm(r["cor"], r["cor_std"]))}</td>')
        body.append(f'<tr>{_cell(r["index"], "d")}{_cell(r["t"], ".4f")}<td>{e(str(r["plate"]))}</td>'
                    f'{_cell(r["speed_in"], ".4f")}{_cell(r["speed_out"], ".4f")}{cor}'
                    f'<td>{e(effect_label(r["cor_method"]))}</td><td>{e(", ".join(r["flags"]))}</td></tr>')
    head = "".join(f"<th>{h}</th>" for h in ("index", "time (s)", "plate", "rel. speed in (m/s)",
                                             "rel. speed out (m/s)", "COR &plusmn; sigma", "COR method", "flags"))
    return (f'<h2>Impacts</h2><p>{len(rows)} impact(s); click a column header to sort (again to reverse). '
            "Relative speeds are |ball velocity - structure velocity| just before (in) and after (out) the "
            "impact; COR method: paper (Eq. 15-16) or the final model's effects that re-measured it. All columns: "
            f'<a href="{e(csv_name)}">{e(csv_name)}</a>.</p>'
            '<div style="max-height:32em;overflow-y:auto;display:inline-block">'
            f'<table class="sortable" id="impacts"><thead><tr>{head}</tr></thead><tbody>{"".join(body)}</tbody>'
            f"</table></div>{SORT_JS}")
