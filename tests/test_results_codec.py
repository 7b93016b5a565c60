"""The one results codec (vibro_model) and the message converters (vibro_ros.convert): round trips of every
type, validation of a document read back, one schema, one sanitiser, one gravity."""

from __future__ import annotations

import ast
import dataclasses
import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from vibro_io.results_file import read_results, write_results
from vibro_model.codec import SCHEMA, ResultsError, json_value
from vibro_model.results import (
    CorSummary,
    Discrepancy,
    DiscrepancyFinding,
    Flight,
    Impact,
    PlateCor,
    ResultsDocument,
    Simulation,
    SimulationRun,
    StructureMotion,
)
from vibro_ros import convert

REPO = Path(__file__).resolve().parents[1]
#: a mm <-> m conversion is one correctly rounded division or multiplication by 1000: there and back,
#: a value moves by at most one unit in the last place (relative 2.2e-16); 2 ulp of margin
ULP2 = 4.5e-16


def _structure() -> StructureMotion:
    return StructureMotion(amplitude_m=3.017e-3, frequency_hz=22.0131, phase_rad=0.3141, offset_m=-1.2e-5,
                           rms_residual_m=4.1e-7, amplitude_std_m=2.2e-6, frequency_std_hz=1.3e-4,
                           phase_std_rad=7.7e-4, offset_std_m=3.1e-7, n_points=399, ball_offset_m=2.31e-4)


def _flights() -> list[Flight]:
    return [Flight(index=0, t_first_frame_s=0.01, t_last_frame_s=0.031, a_mps2=-4.9041, b_mps=0.7712, c_m=-0.0123,
                   direction="up", friction_n=-7.1e-5, friction_std_n=2.0e-6, rms_residual_m=5.1e-7, n_points=21,
                   free=True, reason=""),
            Flight(index=1, t_first_frame_s=0.034, t_last_frame_s=0.052, a_mps2=-4.8977, b_mps=1.1201, c_m=-0.0231,
                   direction="down", friction_n=3.6e-5, friction_std_n=1.9e-6, rms_residual_m=4.8e-7, n_points=19,
                   free=True, reason=""),
            Flight(index=2, t_first_frame_s=0.055, t_last_frame_s=0.057, a_mps2=None, b_mps=None, c_m=None,
                   direction="down", friction_n=None, friction_std_n=None, rms_residual_m=None, n_points=3, free=False,
                   reason="too few points (3 < 6)")]


def _impacts() -> list[Impact]:
    return [Impact(index=0, t_s=0.0325, plate="top", cor=0.7013, cor_std=0.0041, v_ball_before_mps=0.512,
                   v_ball_after_mps=-0.359, v_structure_mps=0.0012, t_std_s=3.1e-6, flight_before=0, flight_after=1,
                   method="paper"),
            Impact(index=1, t_s=0.0531, plate="bottom", cor=0.6987, cor_std=0.0052, v_ball_before_mps=-0.488,
                   v_ball_after_mps=0.341, v_structure_mps=-0.0009, t_std_s=2.7e-6, flight_before=1, flight_after=2,
                   method="paper")]


def _document() -> ResultsDocument:
    finding = DiscrepancyFinding("coulomb_friction", {"force_n": 1.52e-4}, "flights: up flights decelerate", 0.031,
                                 0.004, {"force_n": 3.1e-6}, {"one_step_before": {"rms": 1.0}})
    unexplained = DiscrepancyFinding("unexplained", {}, "impacts drift", 0.004, 0.004)
    return ResultsDocument.build(
        "rec", _structure(), _flights(), _impacts(),
        simulation=Simulation.of_deviations({"cor_model": 0.021, "hertz_model": None}),
        discrepancy=Discrepancy(0.031, [finding, unexplained], 0.004, {"model": "baseline+coulomb_friction"}),
        warnings=["flight 2 is not a free flight"], sections={"regime": {"name": "two_impacts_per_cycle"}})


def _assert_same(a, b, rel: float = 0.0) -> None:
    """Field by field: strings, ints, bools, None exactly; floats to ``rel`` (0: exactly)."""
    if dataclasses.is_dataclass(a):
        assert type(a) is type(b)
        for f in dataclasses.fields(a):
            _assert_same(getattr(a, f.name), getattr(b, f.name), rel)
    elif isinstance(a, dict):
        assert list(a) == list(b)
        for k in a:
            _assert_same(a[k], b[k], rel)
    elif isinstance(a, np.ndarray):
        np.testing.assert_allclose(a, b, rtol=rel, atol=0)
    elif isinstance(a, (list, tuple)):
        assert len(a) == len(b)
        for x, y in zip(a, b):
            _assert_same(x, y, rel)
    elif isinstance(a, float) and not isinstance(a, bool):
        assert isinstance(b, float) and math.isclose(a, b, rel_tol=rel, abs_tol=0.0), (a, b)
    else:
        assert a == b and type(a) is type(b), (a, b)


# ---------------------------------------------------------------- model <-> results.json
def test_every_type_round_trips_through_its_results_json_keys() -> None:
    doc = _document()
    for item, cls in [(doc.structure, StructureMotion), *((f, Flight) for f in doc.flights),
                      *((i, Impact) for i in doc.impacts), (doc.cor_summary, CorSummary), (doc.simulation, Simulation),
                      *((f, DiscrepancyFinding) for f in doc.discrepancy.findings), (doc.discrepancy, Discrepancy)]:
        back = cls.from_dict(json.loads(json.dumps(item.to_dict())))
        _assert_same(item, back, ULP2)  # only the mm <-> m conversion rounds; everything else exact
    back = ResultsDocument.from_dict(json.loads(json.dumps(doc.to_dict())))
    _assert_same(doc, back, ULP2)
    # and the dict itself is a fixed point: dict -> model -> dict is the same text
    assert json.dumps(back.to_dict()) == json.dumps(ResultsDocument.from_dict(back.to_dict()).to_dict())


def test_written_keys_follow_the_contract(tmp_path: Path) -> None:
    doc = _document()
    data = json.loads(write_results(tmp_path / "results.json", doc).read_text())
    assert data["schema"] == SCHEMA == "vibro.results/1" and data["complete"] is True
    # mm at the edge, SI inside: 3.017e-3 m amplitude is 3.017 mm; Y[mm] = a t^2 + b t + c
    assert data["structure"]["amplitude_mm"] == pytest.approx(3.017, rel=1e-15)
    f0 = data["flights"][0]
    assert f0["a"] == pytest.approx(-4904.1, rel=1e-15) and f0["c"] == pytest.approx(-12.3, rel=1e-15)
    # a flight opened and closed by impacts starts/ends at them; its fitted frames stay beside
    assert (f0["t_start"], f0["t_first_frame"]) == (0.01,
                                                    0.01) and f0["t_end"] == 0.0325 and f0["t_last_frame"] == 0.031
    assert data["flights"][1]["t_start"] == 0.0325 and data["flights"][1]["free"] is True
    assert data["flights"][2]["friction_n"] is None and data["flights"][2]["free"] is False
    assert data["impacts"][0]["v_ball_before"] == 0.512  # m/s in and out
    assert data["cor_summary"]["top"] == {"mean": 0.7013, "std": None, "n": 1}
    assert data["simulation"] == {"cor_model": {"deviation": 0.021}, "hertz_model": {"deviation": None}}
    assert data["discrepancy"]["model"] == "baseline+coulomb_friction"
    assert "parameters_std" not in data["discrepancy"]["findings"][1]
    assert data["regime"] == {"name": "two_impacts_per_cycle"}


def test_cor_summary_is_the_sample_statistics() -> None:
    rng = np.random.default_rng(3)
    cors = 0.7 + 0.03 * rng.standard_normal(50)
    imps = [Impact(index=k, t_s=0.01 * k, plate="bottom", cor=float(c), cor_std=0.0, v_ball_before_mps=-1.0,
                   v_ball_after_mps=0.7, v_structure_mps=0.0) for k, c in enumerate(cors)]
    s = CorSummary.of(imps)
    assert s.bottom.n == 50 and s.bottom.mean == pytest.approx(cors.mean(), rel=1e-14)
    assert s.bottom.std == pytest.approx(cors.std(ddof=1), rel=1e-12)
    assert s.top == PlateCor(None, None, 0)


def test_sanitiser_makes_plain_json() -> None:
    out = json_value({"a": np.float32(1.5), "b": [np.nan, np.inf, np.int64(3)], "c": np.array([1.0, -np.inf]),
                      "d": np.bool_(True), 4: None})
    assert out == {"a": 1.5, "b": [None, None, 3], "c": [1.0, None], "d": True, "4": None}
    json.dumps(out, allow_nan=False)


@pytest.mark.parametrize("path, value, expect", [
    (("flights", 1, "t_start"), "0.1", "flights[1].t_start: must be a finite number, got '0.1'"),
    (("flights", 0, "direction"), "sideways", "flights[0].direction: must be one of up, down, got 'sideways'"),
    (("impacts", 1, "plate"), "left", "impacts[1].plate: must be one of top, bottom"),
    (("impacts", 0, "index"), 1.5, "impacts[0].index: must be an integer"),
    (("structure", "amplitude_mm"), None, None),  # null is a valid "unknown"
    (("cor_summary", "top", "n"), "1", "cor_summary.top.n: must be an integer"),
    (("simulation", "cor_model"), 0.02, "simulation.cor_model: expected a mapping"),
    (("discrepancy", "findings", 0, "parameters", "force_n"), "big",
     "discrepancy.findings[0].parameters.force_n: must be a finite number"),
    (("schema",), "vibro.results/2", "schema: expected 'vibro.results/1'"),
])
def test_reader_names_the_bad_key(tmp_path: Path, path: tuple, value, expect) -> None:
    data = _document().to_dict()
    node = data
    for key in path[:-1]:
        node = node[key]
    node[path[-1]] = value
    (tmp_path / "results.json").write_text(json.dumps(data))
    if expect is None:
        assert read_results(tmp_path / "results.json").structure.amplitude_m is None
        return
    with pytest.raises(ResultsError) as err:
        read_results(tmp_path / "results.json")
    assert str(err.value).startswith(f"{tmp_path / 'results.json'}.") and expect in str(err.value)


def test_reader_refuses_missing_sections_and_a_complete_document_without_structure(tmp_path: Path) -> None:
    data = _document().to_dict()
    del data["impacts"], data["simulation"]
    with pytest.raises(ResultsError, match="missing key\\(s\\) impacts, simulation"):
        ResultsDocument.from_dict(data, "x.json")
    data = _document().to_dict()
    data["structure"] = None
    with pytest.raises(ResultsError, match="x.json.structure: null in a document marked complete"):
        ResultsDocument.from_dict(data, "x.json")
    data["complete"] = False
    assert ResultsDocument.from_dict(data, "x.json").structure is None
    # the writer validates too: a bad mapping is never written
    data["flights"][0]["a"] = float("nan")
    with pytest.raises(ResultsError, match="flights\\[0\\].a: must be a finite number"):
        write_results(tmp_path / "bad.json", data)
    assert not (tmp_path / "bad.json").exists()


def test_vibro_fit_summary_names_the_bad_key(tmp_path: Path) -> None:
    data = _document().to_dict()
    data["cor_summary"]["bottom"]["mean"] = "0.7"
    (tmp_path / "r.json").write_text(json.dumps(data))
    res = subprocess.run([sys.executable, "-m", "vibro_app.cli", "summary", str(tmp_path / "r.json"), "--out",
                          str(tmp_path / "s.png")], capture_output=True, text=True, timeout=60)
    assert res.returncode == 2 and "cor_summary.bottom.mean: must be a finite number" in res.stderr
    assert "Traceback" not in res.stderr and len(res.stderr.strip().splitlines()) == 1


# ---------------------------------------------------------------- model <-> message
def test_every_type_round_trips_through_its_message() -> None:
    s = _structure()
    _assert_same(s, convert.structure_from_message(convert.structure_to_message(s)), ULP2)
    for f in _flights():  # a message carries the fitted frames; the impacts are linked again from the impacts
        msg = convert.flight_to_message(f, final=True)
        assert msg.final and msg.t_start_s == f.t_first_frame_s
        _assert_same(f, convert.flight_from_message(msg), ULP2)
    assert math.isnan(convert.flight_to_message(_flights()[2]).friction_n)  # unknown: NaN on the wire
    for i in _impacts():
        _assert_same(dataclasses.replace(i, method=None), convert.impact_from_message(convert.impact_to_message(i)),
                     ULP2)
    for fd in _document().discrepancy.findings:
        back = convert.finding_from_message(convert.finding_to_message(fd, 3, 0.4))
        _assert_same(dataclasses.replace(fd, details={}), back, ULP2)
    t = np.linspace(0.0, 0.3, 301)
    run = SimulationRun("hertz_model", 0.0213, 14, t, 1e-3 * np.sin(40 * t), 1.01e-3 * np.sin(40 * t))
    back = convert.simulation_run_from_message(convert.simulation_run_to_message(run))
    _assert_same(run, back, ULP2)  # the curves too (arrays compared element-wise)
    assert back.ball_m.size == 301


def test_one_gravity_one_schema_one_sanitiser() -> None:
    src = REPO / "src"
    texts = {p: p.read_text() for p in src.rglob("*.py")}
    gravity = [p.name for p, t in texts.items()
               if any(isinstance(n, ast.Constant) and n.value == 9.81 for n in ast.walk(ast.parse(t)))]
    assert gravity == ["constants.py"]
    assert [p.name for p, t in texts.items() if '"vibro.results/1"' in t] == ["codec.py"]
    assert [p.name for p, t in texts.items() if "math.isfinite(x) else None" in t] == ["codec.py"]
