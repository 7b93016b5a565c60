"""``vibro results <bag>``: the results.json of a recorded graph run, rebuilt from its messages.

Flights and impacts marked ``final`` (the fitter's end-of-stream pass) replace the streamed
previews; a bag cut short keeps the streamed ones. Keys and units follow docs/recording-format.md.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

from vibro_ros import topics
from vibro_ros.bags import deserialize, make_typestore, read_messages
from vibro_io.errors import RecordingError
from vibro_io.outputs import atomic_write_text, prepare_output_dir, prepare_output_file

SCHEMA = "vibro.results/1"


def _num(x):
    x = float(x)
    return x if math.isfinite(x) else None


def results_from_bag(bag: str | Path) -> dict:
    """Read every result topic of a bag and assemble the contract's results mapping."""
    store = make_typestore()
    structure = None
    flights: dict[int, object] = {}
    impacts: dict[int, object] = {}
    simulation: dict[str, object] = {}
    findings: dict[int, object] = {}
    final_flights: dict[int, object] = {}
    final_impacts: dict[int, object] = {}
    wanted = {topics.STRUCTURE.name, topics.FLIGHTS.name, topics.IMPACTS.name, topics.SIMULATION.name,
              topics.DISCREPANCY.name}
    for m in read_messages(bag, wanted):
        msg = deserialize(m, store)
        if m.topic == topics.STRUCTURE.name:
            structure = msg
        elif m.topic == topics.FLIGHTS.name:
            (final_flights if msg.final else flights)[msg.index] = msg
        elif m.topic == topics.IMPACTS.name:
            (final_impacts if msg.final else impacts)[msg.index] = msg
        elif m.topic == topics.SIMULATION.name:
            simulation[msg.model] = msg
        else:
            findings[msg.index] = msg
    if structure is None:
        raise RecordingError(f"{bag}: no {topics.STRUCTURE.name} message: the fitter never finished in this bag")
    from vibro_fit.statistics import cor_summary

    if final_impacts or final_flights:  # the fitter finished: its final pass replaces the streamed previews
        flights, impacts = final_flights, final_impacts

    imp = [impacts[k] for k in sorted(impacts)]
    d_cor = simulation["cor_model"].deviation if "cor_model" in simulation else None
    found = [findings[k] for k in sorted(findings)]
    return {
        "schema": SCHEMA,
        "recording": str(bag),
        "structure": {"amplitude_mm": structure.amplitude_mm, "frequency_hz": structure.frequency_hz,
                      "phase_rad": structure.phase_rad, "offset_mm": structure.offset_mm,
                      "rms_residual_mm": structure.rms_residual_mm, "ball_offset_mm": structure.ball_offset_mm},
        "flights": [{"index": f.index, "t_start": f.t_start_s, "t_end": f.t_end_s, "a": f.a_mm_per_s2,
                     "b": f.b_mm_per_s, "c": f.c_mm, "direction": f.direction or "up",
                     "friction_n": _num(f.friction_n), "rms_residual_mm": _num(f.rms_residual_mm),
                     "fitted": f.fitted} for f in (flights[k] for k in sorted(flights))],
        "impacts": [{"index": i.index, "t": i.t_s, "plate": i.plate, "cor": i.cor, "cor_std": _num(i.cor_std),
                     "v_ball_before": i.v_ball_before_m_per_s, "v_ball_after": i.v_ball_after_m_per_s,
                     "v_structure": i.v_structure_m_per_s} for i in imp],
        "cor_summary": cor_summary(imp),
        "simulation": {name: {"deviation": simulation[name].deviation if name in simulation else None}
                       for name in ("cor_model", "hertz_model")},
        "discrepancy": {
            "baseline_deviation": found[0].deviation_before if found else d_cor,
            "findings": [{"effect": f.effect, "parameters": dict(zip(f.parameter_names, f.parameter_values)),
                          "where": f.where, "deviation_before": f.deviation_before,
                          "deviation_after": f.deviation_after} for f in found],
            "final_deviation": found[-1].deviation_after if found else d_cor,
        },
    }


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("results", help="extract results.json from a recorded graph bag")
    p.add_argument("bag", help="bag directory (rosbag2, MCAP storage)")
    p.add_argument("--out", help="write results.json into this folder (created; must be empty unless "
                                 "--overwrite), or to this file if the name ends in .json (default: print it)")
    p.add_argument("--overwrite", action="store_true",
                   help="replace the results.json of an earlier 'vibro results' in --out")
    p.set_defaults(func=run)


def prepare_results_path(out: str | Path, overwrite: bool, inputs: list[Path]) -> Path:
    """Where ``vibro results --out OUT`` writes: OUT itself if it ends in .json, else OUT/results.json
    (OUT prepared by :func:`vibro_io.outputs.prepare_output_dir`)."""
    from vibro_fit.results import RESULTS_JSON

    out = Path(out)
    if out.suffix == ".json":
        return prepare_output_file(out, overwrite=overwrite)
    prepare_output_dir(out, overwrite=overwrite, owned=(RESULTS_JSON,), command="results", inputs=inputs)
    return out / RESULTS_JSON


def run(args: argparse.Namespace) -> int:
    doc = results_from_bag(args.bag)
    text = json.dumps(doc, indent=2) + "\n"
    if args.out:
        bag = Path(args.bag)  # the bag and its graph logs may sit in --out: inputs, kept
        out = prepare_results_path(args.out, args.overwrite, [bag, bag.parent / f"{bag.name}.logs"])
        atomic_write_text(out, text)
        print(f"wrote {out}")
    else:
        print(text, end="")
    return 0
