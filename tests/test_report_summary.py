"""The report opens with a summary (issue #29): parsed from report.html, its numbers are results.json's to the
printed digits, it names no internal key, the finding is one sentence stated once, and no text of the page is
stated twice."""

from __future__ import annotations

import json
import re
from html.parser import HTMLParser

import pytest

from vibro_app.cli import main
from vibro_app.findings_text import value_pm
from vibro_app.report import clauses, write_html
from vibro_fit.identify import track_rows
from vibro_fit.synthetic import accel_signals, paper_rig, sample_track, simulate
from vibro_io.accel import write_accel
from vibro_io.dictrack import write_dic_csv
from vibro_io.rig import write_rig

M_KG = 1.82e-4
PM = r"(-?\d+(?:\.\d+)?) ± (\d+(?:\.\d+)?)"


class Page(HTMLParser):
    """The page's visible text, and the summary's rows: data-key -> (label, value text)."""

    def __init__(self) -> None:
        super().__init__()
        self.text: list[str] = []
        self.rows: dict[str, list[str]] = {}
        self.summary_text: list[str] = []
        self._in_summary = 0
        self._key: str | None = None
        self._cell: list[str] | None = None
        self._skip = 0
        self._verbatim: str | None = None   # a quoted user file or command (data-verbatim): the user's words

    def handle_starttag(self, tag, attrs):
        attrs = dict(attrs)
        if tag in ("style", "title", "script"):
            self._skip += 1
        if "data-verbatim" in attrs:
            self._skip, self._verbatim = self._skip + 1, tag
        if tag == "section" and attrs.get("id") == "summary":
            self._in_summary = 1
        elif self._in_summary and tag == "section":
            self._in_summary += 1
        if self._in_summary and tag == "tr" and "data-key" in attrs:
            self._key = attrs["data-key"]
            assert self._key not in self.rows, f"data-key {self._key} twice"
            self.rows[self._key] = []
        if self._key and tag in ("th", "td"):
            self._cell = []
        if tag in ("br", "li", "tr", "p", "td", "th", "h1", "h2"):
            self.text.append("\n")
            if self._cell is not None:
                self._cell.append(" ")

    def handle_endtag(self, tag):
        if tag in ("style", "title", "script"):
            self._skip -= 1
        if tag == self._verbatim:
            self._skip, self._verbatim = self._skip - 1, None
        if self._key and tag in ("th", "td") and self._cell is not None:
            self.rows[self._key].append(" ".join("".join(self._cell).split()))
            self._cell = None
        if tag == "tr":
            self._key = None
        if tag == "section" and self._in_summary:
            self._in_summary -= 1

    def handle_data(self, data):
        if self._skip:
            return
        self.text.append(data)
        if self._cell is not None:
            self._cell.append(data)
        if self._in_summary:
            self.summary_text.append(data)


def parse(path) -> Page:
    page = Page()
    page.feed(path.read_text(encoding="utf-8"))
    assert page.rows, "no <section id=summary> rows with data-key"
    return page


def decimals(number: str) -> int:
    return len(number.split(".")[1]) if "." in number else 0


def assert_printed(printed: str, value: float, what: str) -> None:
    """``printed`` is ``value`` rounded to the digits it shows."""
    assert abs(float(printed) - value) <= 0.5 * 10 ** -decimals(printed) * (1 + 1e-9) + 1e-15, (what, printed, value)


def assert_pm(text: str, value: float, sigma: float, what: str, scale: float = 1.0) -> None:
    """``text`` is ``value ± sigma`` (times ``scale``) rounded as a measurement: sigma to 2 significant digits,
    the value to the same decimal place."""
    m = re.fullmatch(PM, text)
    assert m, (what, text)
    v, s = m.groups()
    assert decimals(v) == decimals(s), (what, text)
    assert len(s.replace(".", "").lstrip("0")) == 2, (what, text)  # 2 significant digits of sigma
    assert_printed(v, scale * value, what)
    assert_printed(s, scale * sigma, what)


def keys_of(doc) -> set[str]:
    """Every key of a JSON document, at any depth."""
    if isinstance(doc, dict):
        return set(doc) | set().union(*(keys_of(v) for v in doc.values()))
    if isinstance(doc, list):
        return set().union(*(keys_of(v) for v in doc)) if doc else set()
    return set()


@pytest.fixture(scope="module")
def analysed(tmp_path_factory):
    """A 400-frame recording whose plates restitute 0.6 (top) and 0.75 (bottom), COR scatter 0.03, with its
    accelerometers, analysed from its track (no DIC: a few seconds): (results.json, report.html path)."""
    base = tmp_path_factory.mktemp("report_summary")  # its own folder: dic.csv and out/ beside rec/, no other module's
    rec = base / "rec"
    rec.mkdir()
    rig = paper_rig(accelerometers=True)
    write_rig(rig, rec / "rig.yaml")
    truth = simulate(amplitude_m=3e-3, duration_s=0.45, cor_jitter=0.03, seed=9,
                     force_up_n=-0.04 * M_KG * 9.81, force_down_n=0.02 * M_KG * 9.81)
    write_dic_csv(base / "dic.csv", track_rows(sample_track(truth, n_frames=400, noise_mm=0.0005)))
    write_accel(rec / "accel.csv", accel_signals(truth, duration_s=0.4, offset_s=0.003), rig.accelerometers)
    out = base / "out"
    assert main(["analyze", str(rec), "--out", str(out), "--track", str(base / "dic.csv"),
                 "--no-progress"]) == 0
    return json.loads((out / "results.json").read_text()), out / "report.html"


def test_value_pm_rounds_as_a_measurement():
    assert value_pm(0.70012, 0.01534) == "0.700 ± 0.015"
    assert value_pm(1.23449, 0.0021, "mm") == "1.2345 ± 0.0021 mm"
    assert value_pm(1234.5, 23.0, "Hz") == "1234 ± 23 Hz"
    assert value_pm(0.5, None) == "0.5" and value_pm(0.5, 0.0) == "0.5"


def test_summary_numbers_are_the_results(analysed):
    doc, report = analysed
    page = parse(report)
    rows = page.rows
    text = "".join(page.text)
    assert text.index("Summary") < text.index("Structure")  # the summary first, then the details
    assert list(rows)[0] == "recording" and doc["recording"] in rows["recording"][1]
    assert f"{len(doc['flights'])} flights, {len(doc['impacts'])} impacts" in rows["recording"][1]
    # COR per plate: mean ± std (n) of results.json's cor_summary
    assert {k for k in rows if k.startswith("cor.")} == {f"cor.{p}" for p in doc["cor_summary"]}
    for plate, s in doc["cor_summary"].items():
        label, value = rows[f"cor.{plate}"]
        assert plate in label and "COR" in label
        m = re.fullmatch(PM + r" \(n = (\d+)\)", value)
        assert m, value
        assert_pm(f"{m[1]} ± {m[2]}", s["mean"], s["std"], f"COR {plate}")
        assert int(m[3]) == s["n"] > 2
    # the plates differ (0.6 vs 0.75) and the scatter (0.03) shows: not a toy's std of zero
    assert float(rows["cor.top"][1].split()[0]) < float(rows["cor.bottom"][1].split()[0])
    # excitation: the structure's amplitude and frequency with their sigmas and units
    m = re.fullmatch(f"amplitude {PM} mm at {PM} Hz", rows["excitation"][1])
    assert m, rows["excitation"][1]
    st = doc["structure"]
    assert_pm(f"{m[1]} ± {m[2]}", st["amplitude_mm"], st["amplitude_std_mm"], "amplitude")
    assert_pm(f"{m[3]} ± {m[4]}", st["frequency_hz"], st["frequency_std_hz"], "frequency")
    # regime in words, with its cycles
    regime = doc["regime"]
    assert rows["regime"][1] == f"{regime['name'].replace('_', ' ')} over {round(regime['n_cycles'])} excitation cycles"
    assert rows["complete"][1] == ("complete" if doc["complete"] else "incomplete")
    if doc["warnings"]:
        assert all(" ".join(w.split()) in rows["warnings"][1] for w in doc["warnings"])
    else:
        assert rows["warnings"][1] == "none"


def test_findings_are_one_sentence_each_with_their_evidence(analysed):
    doc, report = analysed
    page = parse(report)
    text = " ".join("".join(page.text).split())
    findings = doc["discrepancy"]["findings"]
    assert "asymmetric_restitution" in [f["effect"] for f in findings]
    assert [k for k in page.rows if k.startswith("finding")] == [f"finding.{k}" for k in range(len(findings))]
    sentence_re = (r"(?:The model leaves out (.+?)(?: \((.+)\))?; with it, |A mismatch no modelled effect accounts "
                   r"for remains; )D (?:falls from ([\d.]+) % to ([\d.]+) %|stays at ([\d.]+) %(?: and .+ falls from "
                   r"([\d.]+) to ([\d.]+)(?: \S+)?)?)\.")
    for k, f in enumerate(findings):
        label, sentence = page.rows[f"finding.{k}"]
        assert label == ("Findings" if k == 0 else "")
        assert text.count(sentence) == 1  # stated once in the whole page
        m = re.fullmatch(sentence_re, sentence)
        assert m, sentence
        before, after = (float(f"{100 * f[key]:.3g}") for key in ("deviation_before", "deviation_after"))
        if m[3]:  # D falls: its evidence
            assert (float(m[3]), float(m[4])) == (before, after) and after < before
        else:  # D does not change (a COR law, nothing modelled): the one-step residual it lowers, if any
            assert float(m[5]) == before == after
            if m[6]:
                pairs = {(float(f"{s * f['one_step_before'][key]:.3g}"), float(f"{s * f['one_step_after'][key]:.3g}"))
                         for key in f["one_step_before"] for s in (1.0, 1e3)}
                assert (float(m[6]), float(m[7])) in pairs and float(m[7]) < float(m[6])
        if f["effect"] == "asymmetric_restitution":
            assert m[1] == "asymmetric restitution"
            p = re.fullmatch(f"COR top {PM}, COR bottom {PM}", m[2])
            assert p, m[2]
            assert_pm(f"{p[1]} ± {p[2]}", f["parameters"]["cor_top"], f["parameters_std"]["cor_top"], "cor_top")
            assert_pm(f"{p[3]} ± {p[4]}", f["parameters"]["cor_bottom"], f["parameters_std"]["cor_bottom"],
                      "cor_bottom")
            assert m[6], "a COR law's evidence is the impacts' one-step residual"
    # several findings: the final model's D, baseline -> final
    m = re.fullmatch(r"the baseline with (.+): D ([\d.]+) % → ([\d.]+) %", page.rows["final_model"][1])
    assert m, page.rows["final_model"]
    disc = doc["discrepancy"]
    assert float(m[2]) == float(f"{100 * disc['baseline_deviation']:.3g}")
    assert float(m[3]) == float(f"{100 * disc['final_deviation']:.3g}")


def test_no_key_names_and_each_text_once(analysed):
    doc, report = analysed
    page = parse(report)
    summary = " ".join("".join(page.summary_text).split()).replace(doc["recording"], "")
    text = " ".join("".join(page.text).split()).replace(doc["recording"], "")
    # no internal name in the summary: no results.json key, no snake_case word at all, no regime/effect key
    keys = {k for k in keys_of(doc) if "_" in k}
    assert "amplitude_std_mm" in keys and "cor_top" in keys  # the document's keys were collected
    assert not re.findall(r"\b[a-z0-9]+_[a-z0-9_]+\b", summary), summary
    assert "moving" not in summary and doc["regime"]["name"] not in summary
    # nor anywhere a user reads on the page (tooltips excepted); warnings are other modules' words
    page_words = text
    for w in doc["warnings"]:
        page_words = page_words.replace(" ".join(w.split()), "")
    assert sorted(k for k in keys if re.search(rf"\b{re.escape(k)}\b", page_words)) == []
    # the baseline's location is stated once; no clause of a finding's 'where' repeats it
    loc = doc["discrepancy"]["location"]["text"]
    assert text.count(" ".join(loc.split())) == 1
    for f in doc["discrepancy"]["findings"]:
        for c in clauses(f["where"]) + clauses(loc):
            assert text.count(" ".join(c.split())) <= 1, c


def test_incomplete_results_say_what_was_lost(analysed, tmp_path):
    doc, _ = analysed
    lost = "bag cut short: the discrepancy node's end of stream; flights and impacts without a final estimate"
    other = "accelerometer channel lower clips at 49.0 m/s^2 in 2 impacts"
    partial = dict(doc, complete=False, warnings=[lost, other])
    page = parse(write_html(partial, {}, tmp_path / "report.html"))
    assert page.rows["complete"][1] == f"incomplete {lost}"
    assert page.rows["warnings"][1] == other
    text = " ".join("".join(page.text).split())
    assert text.count(lost) == 1 and text.count(other) == 1
