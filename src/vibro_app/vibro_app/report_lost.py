"""The report's *What was lost and why*: frames without DIC, DIC subsets left out, frame slots a graph run never
answered, runs of lost frames between flights, impacts without a COR, flights that are not free or too short to
fit, results withheld; one row each, read from results.json alone (``dic_quality``, ``completeness``,
``identification``, ``flights``, ``impacts``, ``consistency``, ``discrepancy``; the thresholds from
``provenance.settings`` when recorded).

:func:`lost_rows` gives the rows (plain data: a test reads them back from the page by their ``data-key``);
:func:`lost_html` prints them, or one sentence when nothing was lost.
"""

from __future__ import annotations

import html
from dataclasses import dataclass
from typing import Any, Mapping, Sequence

#: how many places (frames, times) a row lists before it says "…"
MAX_LISTED = 8


@dataclass(frozen=True)
class LostRow:
    """One kind of loss: ``key`` (stable, the row's data-key), ``what`` (words), ``lost`` of ``total`` (None:
    not counted), ``where`` and ``why`` (words)."""

    key: str
    what: str
    lost: int
    total: int | None
    where: str
    why: str


def _listed(items: Sequence[Any], more: int = 0) -> str:
    shown = [str(x) for x in list(items)[:MAX_LISTED]]
    rest = len(items) - len(shown) + more
    return ", ".join(shown) + (f", … ({rest} more)" if rest > 0 else "")


def _settings(results: Mapping[str, Any]) -> Mapping[str, Any]:
    return ((results.get("provenance") or {}).get("settings")) or {}


def _mesh_lost_words(results: Mapping[str, Any]) -> str:
    tracking = (_settings(results).get("dic") or {}).get("tracking") or {}
    if tracking.get("min_valid_fraction") is not None and tracking.get("zncc_min") is not None:
        return (f"fewer than {100 * tracking['min_valid_fraction']:g} % of the body's subsets correlated at "
                f"ZNCC ≥ {tracking['zncc_min']:g}")
    return "too few of the body's subsets correlated"


def frame_rows(results: Mapping[str, Any]) -> list[LostRow]:
    """Per tracked body: frames without a DIC result, and subsets left out before or during tracking."""
    dq = results.get("dic_quality") or {}
    corr = (dq.get("correlation") or {}).get("bodies") or {}
    tex = (dq.get("texture") or {}).get("bodies") or {}
    rows = []
    for body in sorted(corr):
        c = corr[body]
        lost, first = int(c.get("frames_lost") or 0), list(c.get("first_lost") or [])
        rows.append(LostRow(f"frames.{body}", f"frames without DIC ({body})", lost, c.get("frames"),
                            "frames " + _listed(first, lost - len(first)) if lost else "",
                            f"unreadable, or {_mesh_lost_words(results)}" if lost else ""))
    for body in sorted(set(tex) | set(corr)):
        t, c = tex.get(body) or {}, corr.get(body) or {}
        untextured = max(int(t.get("n_subsets") or 0) - int(t.get("n_usable") or 0), 0)
        dropped = list(c.get("subsets_lost") or [])
        why = []
        if untextured:
            why.append(f"{untextured} with too little texture (predicted sigma above "
                       f"{(dq.get('texture') or {}).get('max_subset_sigma_px', '?')} px), left out before tracking")
        if dropped:
            why.append(f"{len(dropped)} kept in fewer than half of the tracked frames")
        rows.append(LostRow(f"subsets.{body}", f"DIC subsets not used ({body})", untextured + len(dropped),
                            t.get("n_subsets"), "subsets " + _listed(dropped) if dropped else "", "; ".join(why)))
    comp = results.get("completeness") or {}
    if comp:
        gaps = comp.get("gaps") or []
        rows.append(LostRow("frames.run", "frame slots the run never answered", int(comp.get("frames_missing") or 0),
                            comp.get("frames_expected"), _listed([f"{g['first']}..{g['last']}" for g in gaps]),
                            "; ".join(sorted({str(g.get("reason", "")) for g in gaps}))))
    return rows


def gap_rows(results: Mapping[str, Any]) -> list[LostRow]:
    """Runs of lost frames between two flights (identification ``gaps``): an impact found inside, or how many it
    may hide."""
    gaps = (results.get("identification") or {}).get("gaps") or []
    hidden = [g for g in gaps if not g.get("determined")]
    where = _listed([f"t = {g['t_start']:.4f}..{g['t_end']:.4f} s ({g['lost_frames']} frames)" for g in gaps])
    why = "; ".join(sorted({str(g.get("reason", "")) for g in hidden if g.get("reason")}))
    found = len(gaps) - len(hidden)
    if found:
        why = (why + "; " if why else "") + f"{found} with an impact found inside from the flights on both sides"
    return [LostRow("gaps", "runs of lost frames between flights (impacts possibly unseen)", len(hidden),
                    len(gaps) or None, where, why)]


def impact_rows(results: Mapping[str, Any]) -> list[LostRow]:
    """Impacts without a COR: those the identification saw without one (short rebound, chatter) and those of
    the impacts table whose COR is unknown."""
    landings = (results.get("identification") or {}).get("impacts_without_cor") or []
    no_cor = [i for i in results.get("impacts") or [] if i.get("cor") is None]
    lost = len(landings) + len(no_cor)
    where = _listed([f"t = {x['t']:.4f} s ({x.get('plate', '?')})" for x in landings]
                    + [f"impact {i.get('index')}" for i in no_cor])
    why = "; ".join(sorted({str(x.get("reason", "")) for x in landings if x.get("reason")}
                           | ({"the flights around it give no COR"} if no_cor else set())))
    return [LostRow("impacts.no_cor", "impacts without a COR", lost, lost + len(results.get("impacts") or [])
                    - len(no_cor), where, why)]


def flight_rows(results: Mapping[str, Any]) -> list[LostRow]:
    """Fitted flights that are not free (no COR, no friction from them) and flights too short to fit."""
    flights = results.get("flights") or []
    not_free = [f for f in flights if not f.get("free", True)]
    short = (results.get("identification") or {}).get("short_flights") or []
    seg = (_settings(results).get("identification") or {}).get("segmentation") or {}
    min_points = seg.get("min_points")
    return [
        LostRow("flights.not_free", "flights not free (no COR or friction from them)", len(not_free), len(flights),
                _listed([f"flight {f.get('index')}" for f in not_free]),
                "; ".join(sorted({str(f.get("reason", "")) for f in not_free if f.get("reason")}))),
        LostRow("flights.short", "flights too short to fit", len(short), len(short) + len(flights),
                _listed([f"t = {f['t_start']:.4f} s ({f.get('n_points')} frames)" for f in short]),
                (f"fewer than {min_points} frames" if min_points is not None else "too few frames") if short else ""),
    ]


def withheld_rows(results: Mapping[str, Any]) -> list[LostRow]:
    """Results withheld: a refused run's COR table, a discrepancy analysis skipped or failed."""
    rows = []
    cons = results.get("consistency") or {}
    if cons.get("refused"):
        refusal = next((w[len("refused: "):] for w in results.get("warnings") or [] if w.startswith("refused: ")),
                       "the cross-checks refused the run")
        rows.append(LostRow("refused", "COR table withheld", 1, 1, "all impacts", refusal))
    disc = results.get("discrepancy") or {}
    reason = disc.get("error") or disc.get("skipped")
    if reason:
        rows.append(LostRow("discrepancy", "discrepancy analysis not done", 1, 1, "", str(reason)))
    return rows


def lost_rows(results: Mapping[str, Any]) -> list[LostRow]:
    """Every row of the table (losses of zero included)."""
    return (frame_rows(results) + gap_rows(results) + impact_rows(results) + flight_rows(results)
            + withheld_rows(results))


def _count(n: int | None) -> str:
    return "" if n is None else str(n)


def lost_html(results: Mapping[str, Any]) -> str:
    """The section: a table of the rows that lost something (``data-key`` per row), or "Nothing lost" with what
    was checked."""
    e = html.escape
    rows = lost_rows(results)
    lost = [r for r in rows if r.lost]
    head = '<section id="lost"><h2>What was lost and why</h2>'
    if not lost:
        checked = "; ".join(f"{r.what}: 0" + (f" of {r.total}" if r.total is not None else "") for r in rows)
        return f'{head}<p id="nothing-lost">Nothing lost ({e(checked)}).</p></section>'
    body = "".join(f'<tr data-key="{e(r.key)}"><td>{e(r.what)}</td><td>{r.lost}</td><td>{_count(r.total)}</td>'
                   f"<td>{e(r.where)}</td><td>{e(r.why)}</td></tr>" for r in lost)
    kept = [r for r in rows if not r.lost]
    rest = ("<p>Nothing else lost: " + e("; ".join(f"{r.what}: 0" + (f" of {r.total}" if r.total is not None
                                                                         else "") for r in kept)) + ".</p>"
            if kept else "")
    return (f'{head}<table id="lost-table"><tr><th>what</th><th>lost</th><th>of</th><th>where</th><th>why</th></tr>'
            f"{body}</table>{rest}</section>")
