"""``vibro fit`` (identification from a dic.csv) and ``vibro summary`` (Fig. 14 across recordings)."""

from __future__ import annotations

import json

from vibro_app.cli import main
from vibro_fit.identify import track_rows
from vibro_fit.synthetic import paper_rig, sample_track, simulate
from vibro_io.dictrack import write_dic_csv
from vibro_io.rig import write_rig


def _make(tmp_path, cor_top, cor_bottom, name):
    d = tmp_path / name
    d.mkdir()
    write_rig(paper_rig(), d / "rig.yaml")
    truth = simulate(amplitude_m=3e-3, duration_s=0.45, cor_top=cor_top, cor_bottom=cor_bottom, cor_jitter=0.02)
    write_dic_csv(d / "dic.csv", track_rows(sample_track(truth, n_frames=400)))
    return d, truth


def test_fit_then_summary(tmp_path, capsys):
    outs = []
    for name, (et, eb) in {"t1": (0.6, 0.75), "t2": (0.5, 0.73)}.items():
        d, truth = _make(tmp_path, et, eb, name)
        out = tmp_path / f"{name}_out"
        assert main(["fit", str(d / "dic.csv"), "--rig", str(d / "rig.yaml"), "--out", str(out)]) == 0
        doc = json.loads((out / "results.json").read_text())
        # per-plate means of ~8 impacts with 0.02 scatter: within 4 standard errors (0.02/sqrt(8) x 4)
        assert abs(doc["cor_summary"]["top"]["mean"] - et) < 0.03
        assert abs(doc["cor_summary"]["bottom"]["mean"] - eb) < 0.03
        outs.append(out / "results.json")
    png = tmp_path / "fig14.png"
    assert main(["summary", *map(str, outs), "--out", str(png)]) == 0
    assert png.is_file() and png.with_suffix(".csv").is_file()
    lines = [ln for ln in capsys.readouterr().out.splitlines() if "mean" in ln]
    assert len([ln for ln in lines if ln.startswith("t1_out") or ln.startswith("t2_out")]) == 4


def test_fit_cli_bad_inputs(tmp_path, capsys):
    d, _ = _make(tmp_path, 0.6, 0.75, "r")
    assert main(["fit", str(d / "dic.csv"), "--rig", str(d / "missing.yaml"), "--out", str(tmp_path / "o")]) == 2
    assert "missing.yaml" in capsys.readouterr().err
    # --accel without an accelerometers block in rig.yaml: named
    assert main(["fit", str(d / "dic.csv"), "--rig", str(d / "rig.yaml"), "--accel", str(d / "dic.csv"),
                 "--out", str(tmp_path / "o")]) == 2
    assert "accelerometers" in capsys.readouterr().err
    (tmp_path / "junk.json").write_text("{}")
    assert main(["summary", str(tmp_path / "junk.json"), "--out", str(tmp_path / "x.png")]) == 2
    assert "cor_summary" in capsys.readouterr().err
