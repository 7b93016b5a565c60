"""A rig.yaml that does not name ``dic.ball_method`` (issue 40): the texture of frame 0's ball ROI chooses.

A plain ball (``vibro synth --ball-surface plain``) whose rig.yaml lacks the key, as a hand-written one would,
is tracked by its outline, exactly as with ``ball_method: outline`` named (identical dic.csv), every measurable
true impact found, and results.json ``dic_quality`` says how and why; a speckled ball without the key keeps
the DIC mesh (identical to ``ball_method: mesh`` named); a rig.yaml naming ``mesh`` for a plain ball keeps mesh.
"""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
import yaml
from truth_impacts import measurable_impacts

from vibro_app.cli import main
from vibro_dic.ball_method import choose_ball_method, resolve_ball_method
from vibro_io.recording import open_recording
from vibro_io.rig import load_rig, parse_rig

FRAMES = 400


def _synth(out, surface: str) -> None:
    assert main(["synth", "--ball-surface", surface, "--out", str(out), "--frames", str(FRAMES),
                 "--no-progress"]) == 0


def _with_method(src, dst, method: str | None) -> None:
    """A copy of recording ``src`` at ``dst`` whose rig.yaml names ``method`` (None: no dic.ball_method key)."""
    shutil.copytree(src, dst)
    path = dst / "rig.yaml"
    rig = yaml.safe_load(path.read_text())
    rig["dic"].pop("ball_method", None)
    if method is not None:
        rig["dic"]["ball_method"] = method
    path.write_text(yaml.safe_dump(rig, sort_keys=False))


def _analyze(rec, out) -> tuple[dict, str]:
    assert main(["analyze", str(rec), "--out", str(out), "--no-progress", "--no-report"]) == 0
    return json.loads((out / "results.json").read_text()), (out / "dic.csv").read_text()


@pytest.fixture(scope="module")
def plain(tmp_path_factory):
    base = tmp_path_factory.mktemp("plain")
    _synth(base / "R", "plain")
    truth = json.loads((base / "R.truth.json").read_text())
    _with_method(base / "R", base / "nokey", None)
    _with_method(base / "R", base / "outline", "outline")
    return truth, _analyze(base / "nokey", base / "O_nokey"), _analyze(base / "outline", base / "O_outline"), base


def test_plain_ball_without_the_key_is_tracked_by_its_outline(plain):
    truth, (doc, dic_csv), (doc_named, dic_named), _ = plain
    q = doc["dic_quality"]
    assert q["ball_method"] == "outline"
    assert q["ball_method_source"] == "texture check"
    assert "plain" in q["ball_method_reason"]
    assert doc_named["dic_quality"]["ball_method"] == "outline"
    assert doc_named["dic_quality"]["ball_method_source"] == "rig.yaml"
    assert q["texture"]["bodies"]["ball"]["method"] == "outline"
    assert dic_csv == dic_named  # the same tracking as with the key named
    lost = q["correlation"]["bodies"]["ball"]["frames_lost"]
    assert lost == doc_named["dic_quality"]["correlation"]["bodies"]["ball"]["frames_lost"] == 0
    t_found = np.array([i["t"] for i in doc["impacts"]])
    for imp in measurable_impacts(truth):
        assert np.min(np.abs(t_found - imp["t"])) < 2e-3, f"true impact at t = {imp['t']:.4f} s not found"


def test_plain_ball_named_mesh_keeps_mesh(plain):
    base = plain[3]
    rig = load_rig(base / "R" / "rig.yaml")
    rec = open_recording(base / "R")
    ref = next(iter(rec.frames.iter_slots(0, 1))).image
    data = yaml.safe_load((base / "R" / "rig.yaml").read_text())
    data["dic"]["ball_method"] = "mesh"
    named = parse_rig(data)
    assert named.dic.ball_method_named
    assert choose_ball_method(ref, named.dic) == ("mesh", "named in rig.yaml")
    choice = resolve_ball_method(ref, named.dic)
    assert (choice.source, choice.dic) == ("rig.yaml", named.dic)
    data["dic"].pop("ball_method")
    absent = parse_rig(data)
    assert not absent.dic.ball_method_named
    assert absent.dic.ball_method == "mesh"  # the default until the texture check chooses
    assert "ball_method" not in absent.to_dict()["dic"]
    assert choose_ball_method(ref, absent.dic)[0] == "outline"
    assert rig.dic.ball_method == "outline"  # synth names it for a plain ball


def test_speckled_ball_without_the_key_keeps_mesh(tmp_path):
    _synth(tmp_path / "S", "speckle")
    assert "ball_method" not in yaml.safe_load((tmp_path / "S" / "rig.yaml").read_text())["dic"]
    _with_method(tmp_path / "S", tmp_path / "mesh", "mesh")
    doc, dic_csv = _analyze(tmp_path / "S", tmp_path / "O_nokey")
    doc_named, dic_named = _analyze(tmp_path / "mesh", tmp_path / "O_mesh")
    q = doc["dic_quality"]
    assert (q["ball_method"], q["ball_method_source"]) == ("mesh", "texture check")
    assert (doc_named["dic_quality"]["ball_method"], doc_named["dic_quality"]["ball_method_source"]) == \
        ("mesh", "rig.yaml")
    assert dic_csv == dic_named  # identical to before
