"""Near-chatter with sticking (issue #27 item 1): `vibro synth --cor 0.5` with a drive near g makes the ball,
every cycle, land on the lower plate, hop (8.6, 4.1, 2.0 ms, ... shorter each time) and ride the plate until
the plate's downward acceleration exceeds g and releases it (truth ``contacts``). `vibro analyze` must find
every impact whose hops it can see (the short hops measured on the plate's level, :mod:`vibro_fit.hops`),
with the COR right and its sigma honest, report the riding as ``contacts`` with the regime named, and claim
no catalogue effect on this recording, which has none. A regular two-impact recording is unchanged.

A hop is *seen* when at least 3 frames lie inside it more than MARGIN of a frame interval from both its
impacts (a frame that close to an impact may hold the contact in its exposure: 0.5 ms at 1000 fps covers
0.25 of an interval each side). Numbers at noise 2 gray levels (ball noise about 0.25 um).
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from vibro_app.cli import main

FRAMES = 400
FPS = 1000.0
MARGIN = 0.3            # frame intervals (see module docstring)
SIGMAS = 4.0            # a measured COR agrees with the truth within this many of its own sigmas
CATALOGUE = ("coulomb_friction", "viscous_drag", "quadratic_drag", "asymmetric_restitution",
             "velocity_dependent_restitution", "gravity_tilt", "structure_harmonics")


def _analyze(rec, out):
    rc = main(["analyze", str(rec), "--out", str(out), "--no-progress", "--no-report"])
    assert rc == 0
    return json.loads((out / "results.json").read_text())


@pytest.fixture(scope="module")
def sticking(tmp_path_factory):
    from vibro_sim.synth import SynthConfig, synthesize

    base = tmp_path_factory.mktemp("sticking")
    truth = synthesize(base / "rec", SynthConfig(frames=FRAMES, seed=5, cor=0.5, accel_mps2=13.0, frequency_hz=10.0,
                                                 cor_scatter=0.01), progress=False)
    return truth, _analyze(base / "rec", base / "out")


@pytest.fixture(scope="module")
def regular(tmp_path_factory):
    from vibro_sim.synth import SynthConfig, synthesize

    base = tmp_path_factory.mktemp("regular")
    truth = synthesize(base / "rec", SynthConfig(frames=300, seed=3), progress=False)
    return truth, _analyze(base / "rec", base / "out")


def _frames_inside(t_frames, a, b):
    m = MARGIN / FPS
    return int(np.sum((t_frames > a + m) & (t_frames < b - m)))


def _seen_impacts(truth):
    """True impacts with a seen flight (>= 3 frames, module docstring) on each side, inside the recording."""
    t_frames = np.asarray(truth["frames"]["t_s"])
    flights = truth["flights"]
    out = []
    for i in truth["impacts"]:
        before = [f for f in flights if abs(f["t_end"] - i["t"]) < 1e-9]
        after = [f for f in flights if abs(f["t_start"] - i["t"]) < 1e-9]
        if not before or not after:
            continue
        p, q = before[0], after[0]
        if p["t_start"] < t_frames[0] or q["t_end"] > t_frames[-1]:
            continue
        if _frames_inside(t_frames, p["t_start"], i["t"]) >= 3 and _frames_inside(t_frames, i["t"], q["t_end"]) >= 3:
            out.append(i)
    return out


def _match(found, t_s):
    near = [x for x in found if abs(x["t"] - t_s) < 1.0 / FPS]
    return min(near, key=lambda x: abs(x["t"] - t_s)) if near else None


def test_synth_rides_the_lower_plate(sticking):
    truth, _ = sticking
    assert truth["baseline"]["cor"] == 0.5
    inside = [c for c in truth["contacts"] if not c["starts_before_recording"] and not c["ends_after_recording"]]
    assert len(inside) >= 3 and all(c["plate"] == "bottom" for c in truth["contacts"])
    seen = _seen_impacts(truth)
    # per contact phase the landing and at least one hop after it are seen: short hops, not long flights
    assert len(seen) >= 2 * len(inside)
    hop_s = sorted(q["t_end"] - q["t_start"] for q in truth["flights"]
                   if any(abs(q["t_start"] - i["t"]) < 1e-9 for i in seen))
    assert hop_s[0] < 0.006, hop_s


def test_every_seen_hop_impact_found_with_its_cor(sticking):
    truth, res = sticking
    seen = _seen_impacts(truth)
    found = res["impacts"]
    matched = [(i, _match(found, i["t"])) for i in seen]
    hits = [(i, m) for i, m in matched if m is not None]
    assert len(hits) >= 0.98 * len(seen), [i["t"] for i, m in matched if m is None]
    # nothing invented: every reported impact is a true one
    for x in found:
        assert min(abs(x["t"] - i["t"]) for i in truth["impacts"]) < 1.0 / FPS, x
    errs = np.array([m["cor"] - i["cor"] for i, m in hits])
    assert float(np.mean(np.abs(errs))) <= 0.002, errs
    for i, m in hits:   # the sigma is honest: the error within SIGMAS of it
        assert m["cor_std"] is not None and m["cor_std"] > 0
        assert abs(m["cor"] - i["cor"]) <= SIGMAS * m["cor_std"], (i["t"], m["cor"], i["cor"], m["cor_std"])
    assert all(m["plate"] == "bottom" for _, m in hits)
    assert any(m.get("method") == "hop_chain" for _, m in hits)


def test_contacts_reported_where_the_ball_rides(sticking):
    truth, res = sticking
    found = res["contacts"]
    inside = [c for c in truth["contacts"] if not c["starts_before_recording"] and not c["ends_after_recording"]]
    assert len(found) == len(truth["contacts"])
    for c in inside:
        m = [f for f in found if f["start_s"] < c["end_s"] and f["end_s"] > c["start_s"]]
        assert len(m) == 1, (c, found)
        f = m[0]
        assert f["plate"] == "bottom"
        assert abs(f["start_s"] - c["start_s"]) <= 2.0 / FPS, (f, c)
        assert abs(f["end_s"] - c["end_s"]) <= 2.0 / FPS, (f, c)
    regime = res["regime"]
    assert regime["name"] == "chatter_with_sticking"
    assert "chatter with sticking on the lower plate" in regime["description"]


def test_no_catalogue_effect_claimed_on_a_recording_without_one(sticking):
    truth, res = sticking
    assert truth["effects"] == [{"effect": "none", "parameters": {}}]
    findings = (res.get("discrepancy") or {}).get("findings") or []
    claimed = [f.get("effect") for f in findings if f.get("effect") in CATALOGUE]
    assert claimed == [], findings


def test_regular_recording_has_no_contacts_or_hops(regular):
    truth, res = regular
    assert truth["contacts"] == []
    assert res["contacts"] == []
    assert res["regime"]["name"] == "two_impacts_per_cycle"
    assert all(x.get("method") != "hop_chain" for x in res["impacts"])
    seen = _seen_impacts(truth)
    assert all(_match(res["impacts"], i["t"]) is not None for i in seen)


def test_report_shows_the_contacts(sticking, tmp_path, monkeypatch):
    """The report's page lists every contact phase of results.json (to the printed digits) and the
    displacement figure shades each one that lies in its window, in the plate's colour."""
    import re
    from types import SimpleNamespace

    import vibro_app.report as report

    _, res = sticking
    contacts = res["contacts"]
    assert contacts
    page = report.write_html(res, {}, tmp_path / "report.html").read_text()
    assert "Contact phases" in page
    rows = re.findall(r"<tr><td>(upper|lower)</td><td>([0-9.]+)</td><td>([0-9.]+)</td>", page)
    assert len(rows) == len(contacts)
    for (plate, a, b), c in zip(rows, contacts):
        assert plate == {"top": "upper", "bottom": "lower"}[c["plate"]]
        assert abs(float(a) - c["start_s"]) <= 5e-5 and abs(float(b) - c["end_s"]) <= 5e-5
    # the figure: a stand-in identification holding the contacts; the saved figure is inspected
    t = np.arange(FRAMES) / FPS
    ident = SimpleNamespace(structure=SimpleNamespace(frequency_hz=10.0, position_mm=lambda x: 0.0 * x),
                            flights=[], impacts=[], contacts=contacts)
    track = SimpleNamespace(t_s=t, ball_mm=0.0 * t, structure_mm=0.0 * t)
    saved = {}
    monkeypatch.setattr(report, "save_figure", lambda fig, path: saved.setdefault("fig", fig) and path)
    report.fig_displacements(track, ident, tmp_path / "d.png")
    ax = saved["fig"].axes[0]                      # the whole recording
    spans = sorted((p.get_x(), p.get_x() + p.get_width()) for p in ax.patches)
    assert len(spans) == len(contacts)
    for (a, b), c in zip(spans, sorted(contacts, key=lambda c: c["start_s"])):
        assert a == pytest.approx(c["start_s"], abs=1e-9) and b == pytest.approx(c["end_s"], abs=1e-9)
    assert "riding" in ax.get_title()
    assert any("riding the lower plate" in x.get_text() for x in ax.get_legend().get_texts())
