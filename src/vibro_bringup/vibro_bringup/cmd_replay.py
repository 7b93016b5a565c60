"""``vibro replay <bag> [--out DIR]``: re-run the processing nodes on a bag's recorded raw topics.

The recorded frames and accelerometer blocks go back through the same graph (bag_source
instead of the file sources); the run is recorded to DIR/bag and its results written to
DIR/results.json, so a replay can be compared with the original run.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from vibro_ros.bags import read_custom_data
from vibro_io.errors import RecordingError

from .bag_results import results_from_bag
from .cmd_graph import add_run_options, execute_graph, new_bag_path, prepare_environment, print_summary
from .graph_spec import BAG_SOURCE, reference_from_bag


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("replay", help="re-run the processing nodes on a recorded bag's raw topics")
    p.add_argument("bag", help="bag directory recorded by vibro graph")
    p.add_argument("--out", help="output folder (default: <bag>.replay): bag/ and results.json")
    add_run_options(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    source_bag = Path(args.bag)
    rig_text = read_custom_data(source_bag).get("vibro.rig_yaml")
    if not rig_text:
        raise RecordingError(f"{source_bag}: the bag holds no rig.yaml (metadata custom_data 'vibro.rig_yaml'); "
                             "it was not recorded by vibro graph")
    out = Path(args.out) if args.out else source_bag.parent / f"{source_bag.name}.replay"
    out.mkdir(parents=True, exist_ok=True)
    (out / "rig.yaml").write_text(rig_text, encoding="utf-8")
    bag = new_bag_path(out / "bag")
    env = prepare_environment(args.domain_id)
    with_accel = "accelerometers:" in rig_text
    t0 = time.monotonic()
    ok, summary, log_dir = execute_graph(out, bag, [BAG_SOURCE], with_accel=with_accel, params_base=args.params,
                                         timeout_s=args.timeout_s, env=env,
                                         extra_params={"bag_source": {"bag": str(source_bag.resolve())}},
                                         respawn=args.respawn, namespace=args.namespace,
                                         reference=lambda folder: reference_from_bag(
                                             source_bag, folder / "reference_frame0.png", out / "rig.yaml"))
    print(f"replay: {time.monotonic() - t0:.1f} s, logs in {log_dir}")
    print_summary(summary, bag)
    if ok:
        doc = results_from_bag(bag)
        doc["recording"] = str(source_bag)
        (out / "results.json").write_text(json.dumps(doc, indent=2) + "\n", encoding="utf-8")
        print(f"results: {out / 'results.json'}")
    return 0 if ok else 1
