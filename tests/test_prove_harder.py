"""``vibro prove --harder`` runs end to end on a tiny set and prints one row per case with every criterion
(the pass values of the full set are in the note, not asserted here); the generator's frame drops sit where
the draws say (one impact inside each of the first two runs, none in the third) and the scoring counts a
gap's impact as the gap's, not as a recall miss."""

from __future__ import annotations

import json

import numpy as np

from vibro_app.cli import main
from vibro_eval.harder import CRITERIA, HARDER_FAMILIES, _gap_bounds, draw_harder, measurable_impacts, place_drops


def test_drops_hide_one_impact_each_then_none():
    from vibro_sim.synth.scenario import SynthConfig, build_models
    from vibro_sim.synth.trajectory import simulate_window

    cfg = SynthConfig(frames=400, seed=2)
    traj = simulate_window(cfg, build_models(cfg, 0.4))
    truth = {"frames": {"t_s": list(traj.frame_t_s)},
             "impacts": [{"t": i.t_s, "plate": i.plate} for i in traj.impacts]}
    runs = place_drops(truth, 3, np.random.default_rng(1), cfg.fps)
    assert len(runs) == 3
    tt = np.array([i["t"] for i in truth["impacts"]])
    pl = [i["plate"] for i in truth["impacts"]]
    inside = {}
    for a, c in runs:
        assert 2 <= c <= 6
        lo, hi = _gap_bounds(a, c, cfg.fps)
        inside[(a, c)] = [pl[j] for j in np.flatnonzero((tt > lo) & (tt < hi))]
    assert sorted(map(tuple, inside.values())) == [(), ("bottom",), ("top",)]
    lost = {k for a, c in runs for k in range(a, a + c)}
    hidden_t = [float(t) for t in tt if any(_gap_bounds(a, c, cfg.fps)[0] < t < _gap_bounds(a, c, cfg.fps)[1]
                                            for a, c in runs)]
    truth["flights"] = [{"t_start": f.t_start_s, "t_end": f.t_end_s} for f in traj.flights]
    meas = measurable_impacts(truth, lost, cfg.fps)
    assert not {float(tt[j]) for j in meas} & set(hidden_t)


def test_draws_cover_the_families():
    specs = draw_harder(0, 1000)
    assert {s.family for s in specs} == set(HARDER_FAMILIES)
    for s in specs:
        if s.family == "sticking":
            assert 0.4 <= s.cor <= 0.6 and 9.0 <= s.frequency_hz <= 11.0 and 12.0 <= s.accel_mps2 <= 14.0
        if s.family.startswith("drops"):
            assert s.drops == 3
    assert {s.accel for s in specs if s.family == "drops"} == {True, False}


def test_prove_harder_tiny_set_prints_its_criteria(tmp_path, capsys):
    rc = main(["prove", "--harder", "--cases", "2", "--frames", "300", "--seed", "2", "--out", str(tmp_path),
               "--no-sindy", "--no-progress"])
    assert rc == 0
    out = capsys.readouterr().out
    head = out.splitlines()[0].split()
    for col in ("recall", "R", "I", "G", "C", "findings", "Fd", "Dr", "pass"):
        assert col in head
    proof = json.loads((tmp_path / "proof.json").read_text())
    assert [r["family"] for r in proof["rows"]] == list(HARDER_FAMILIES[:2])
    for r in proof["rows"]:
        assert "error" not in r, r.get("error")
        assert set(r["criteria"]) == set(CRITERIA)
        assert r["measurable"] > 0
    assert proof["rows"][1]["dropped"] and all(g["outcome"] for g in proof["rows"][1]["gaps"])
