"""The report's Table 2 per plate and its per-impact table (issue 39): the statistics against independent
computations (the interval's coverage, Shapiro-Wilk's power and size on simulated samples), and report.html of an
analysed synthetic recording parsed back: both plates with results.json's n, one row per impact with its COR."""

from __future__ import annotations

import json
import math
from html.parser import HTMLParser

import numpy as np
import pytest

from vibro_app.cli import main
from vibro_app.report_tables import (
    impact_rows,
    impacts_table_html,
    mean_interval,
    plate_statistics,
    shapiro_p,
    table2_html,
)
from vibro_fit.identify import track_rows
from vibro_fit.synthetic import paper_rig, sample_track, simulate
from vibro_io.dictrack import write_dic_csv
from vibro_io.rig import write_rig


def _binomial_tolerance(p: float, trials: int, z: float = 4.0) -> float:
    """z binomial standard deviations of a fraction with probability ``p`` over ``trials`` (z = 4: a false
    failure about once in 16 000 runs; the seeds are fixed anyway)."""
    return z * math.sqrt(p * (1 - p) / trials)


@pytest.mark.parametrize("n", [4, 12, 60])
def test_the_interval_of_the_mean_covers_the_true_mean_95_percent_of_the_time(n: int) -> None:
    rng = np.random.default_rng(n)
    trials, mu = 2000, 0.7
    hits = 0
    for _ in range(trials):
        lo, hi = mean_interval(rng.normal(mu, 0.02, n))
        hits += lo <= mu <= hi
    assert abs(hits / trials - 0.95) < _binomial_tolerance(0.95, trials)


def test_shapiro_is_small_on_a_non_normal_sample_and_uniform_on_normal_ones() -> None:
    rng = np.random.default_rng(3)
    assert shapiro_p(rng.exponential(1.0, 200)) < 1e-4
    assert shapiro_p(np.r_[rng.normal(0.6, 0.01, 100), rng.normal(0.8, 0.01, 100)]) < 1e-4  # two modes
    trials = 400
    ps = np.array([shapiro_p(rng.normal(0.7, 0.02, 50)) for _ in range(trials)])
    assert abs(np.mean(ps < 0.05) - 0.05) < _binomial_tolerance(0.05, trials)  # its size: 5 % false alarms
    assert shapiro_p([0.7, 0.71]) is None and shapiro_p(np.full(10, 0.7)) is None
    assert shapiro_p(rng.normal(size=5001)) is None


def test_plate_statistics_are_the_textbook_numbers() -> None:
    rng = np.random.default_rng(1)
    top, bottom = rng.normal(0.6, 0.03, 25), rng.normal(0.75, 0.02, 3)
    imps = [{"plate": "top", "cor": float(c)} for c in top] + [{"plate": "bottom", "cor": float(c)} for c in bottom]
    imps.append({"plate": "bottom", "cor": None})
    s = plate_statistics(imps)
    t = s["top"]
    assert t.n == 25 and t.n_missing == 0
    assert t.mean == pytest.approx(sum(top) / 25, rel=1e-12)
    sd = math.sqrt(sum((c - t.mean) ** 2 for c in top) / 24)
    assert t.std == pytest.approx(sd, rel=1e-10) and t.sem == pytest.approx(sd / 5, rel=1e-10)
    t24 = 2.0638985616280205  # Student t, 24 dof, 0.975 quantile (tables)
    assert t.ci == pytest.approx((t.mean - t24 * sd / 5, t.mean + t24 * sd / 5), rel=1e-9)
    assert 0.9 < t.qq_r <= 1 and 0 < t.shapiro_p <= 1
    b = s["bottom"]
    assert (b.n, b.n_missing) == (3, 1) and b.shapiro_p is not None
    one = plate_statistics([{"plate": "top", "cor": 0.6}])
    assert one["top"].std is None and one["top"].ci is None and one["top"].shapiro_p is None
    assert one["bottom"].n == 0 and one["bottom"].mean is None
    assert "n/a" in table2_html([{"plate": "top", "cor": 0.6}])
    assert table2_html([]) == "" and impacts_table_html([]) == ""


def test_impact_rows_give_relative_speeds_and_flags() -> None:
    imp = {"index": 3, "t": 0.5, "plate": "top", "cor": 0.7, "cor_std": 1e-4, "v_ball_before": 0.9,
           "v_ball_after": -0.3, "v_structure": 0.2, "cor_method": "drag+local_structure", "in_gap": True,
           "gap_lost_frames": 4}
    (row,) = impact_rows([imp])
    assert row["speed_in"] == pytest.approx(0.7) and row["speed_out"] == pytest.approx(0.5)
    assert row["flags"] == ["in lost frames (4 lost)", "local structure"]
    (row,) = impact_rows([dict(imp, cor=None, cor_method=None, in_gap=None)])
    assert row["cor_method"] == "paper" and row["flags"] == ["no COR"]


class Tables(HTMLParser):
    """Table 2's rows (plate -> cell texts), the per-impact table's body rows (cell texts) and its links."""

    def __init__(self) -> None:
        super().__init__()
        self.table2: dict[str, list[str]] = {}
        self.impacts: list[list[str]] = []
        self.links: list[str] = []
        self.scripts = 0
        self._table = None
        self._tbody = False
        self._row: list[str] | None = None
        self._plate = None

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        if tag == "table":
            self._table = a.get("id")
        elif tag == "tbody":
            self._tbody = True
        elif tag == "tr":
            self._row, self._plate = [], a.get("data-plate")
        elif tag in ("td", "th") and self._row is not None:
            self._row.append("")
        elif tag == "a":
            self.links.append(a.get("href", ""))
        elif tag == "script":
            self.scripts += 1

    def handle_endtag(self, tag):
        if tag == "tr" and self._row is not None:
            if self._table == "table2" and self._plate:
                self.table2[self._plate] = self._row
            elif self._table == "impacts" and self._tbody:
                self.impacts.append(self._row)
            self._row = None
        elif tag == "tbody":
            self._tbody = False
        elif tag == "table":
            self._table = None

    def handle_data(self, data):
        if self._row:
            self._row[-1] += data


@pytest.fixture(scope="module")
def analysed(tmp_path_factory):
    """A 400-frame synthetic recording analysed from its track (a few seconds): (results.json, report.html)."""
    base = tmp_path_factory.mktemp("report_tables")  # its own folder: dic.csv and out/ beside rec/, no other module's
    rec = base / "rec"
    rec.mkdir()
    write_rig(paper_rig(), rec / "rig.yaml")
    truth = simulate(amplitude_m=3e-3, duration_s=0.45, cor_jitter=0.03, seed=4)
    write_dic_csv(base / "dic.csv", track_rows(sample_track(truth, n_frames=400, noise_mm=0.0005)))
    out = base / "out"
    assert main(["analyze", str(rec), "--out", str(out), "--track", str(base / "dic.csv"),
                 "--no-progress"]) == 0
    return json.loads((out / "results.json").read_text()), out / "report.html"


def test_the_report_tables_are_results_json(analysed) -> None:
    doc, report = analysed
    page = Tables()
    page.feed(report.read_text())
    assert set(page.table2) == {"top", "bottom"}
    for plate, cells in page.table2.items():
        assert int(cells[1].split()[0]) == doc["cor_summary"][plate]["n"] > 0
        assert float(cells[2]) == pytest.approx(doc["cor_summary"][plate]["mean"], abs=5e-5)
        assert float(cells[3]) == pytest.approx(doc["cor_summary"][plate]["std"], abs=5e-5)
    impacts = doc["impacts"]
    assert len(page.impacts) == len(impacts) > 10
    for cells, imp in zip(page.impacts, impacts):
        assert int(cells[0]) == imp["index"] and cells[2] == imp["plate"]
        printed = cells[5].split("±")[0].strip()
        decimals = len(printed.split(".")[1]) if "." in printed else 0
        assert decimals >= 2 and float(printed) == pytest.approx(imp["cor"], abs=0.51 * 10 ** -decimals)
        assert float(cells[3]) == pytest.approx(abs(imp["v_ball_before"] - imp["v_structure"]), abs=5e-5)
    assert "impacts.csv" in page.links and page.scripts >= 1
