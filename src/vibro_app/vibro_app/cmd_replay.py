"""``vibro replay <bag> [--out DIR]``: re-run the processing nodes on a bag's recorded raw topics.

The recorded frames and accelerometer blocks go back through the same graph (bag_source
instead of the file sources); the run is recorded to DIR/bag and its results written to
DIR/results.json, so a replay can be compared with the original run.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from vibro_app.bag_results import document_from_bag
from vibro_app.cmd_graph import add_run_options, foxglove_parameters, print_summary
from vibro_bringup.graph_runner import GraphRun, bag_outputs, execute_graph, new_bag_path, prepare_environment
from vibro_bringup.graph_spec import BAG_SOURCE, RunSetup, bag_time_origin_ns, frames_topic_of_bag, reference_from_bag
from vibro_io.camera_calibration import write_recorded_calibration
from vibro_io.outputs import atomic_write_text, prepare_output_dir
from vibro_io.results_file import write_results
from vibro_model.errors import RecordingError
from vibro_ros import topics
from vibro_ros.bags import read_custom_data

REPLAY_BAG = "bag"
#: what --overwrite may replace (camera_info.yaml: the lens calibration the recorded rig.yaml names, by that name)
REPLAY_OUTPUTS = ("rig.yaml", "camera_info.yaml", "results.json", *bag_outputs(REPLAY_BAG))


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("replay", help="re-run the processing nodes on a recorded bag's raw topics")
    p.add_argument("bag", help="bag directory recorded by vibro graph")
    p.add_argument("--out", help="output folder (default: <bag>.replay): rig.yaml, bag/, bag.logs/ and results.json; "
                                 "created; must be empty unless --overwrite")
    p.add_argument("--frames-topic", help="the bag's topic of camera images (default: vibro/frames, else the "
                                          "bag's only sensor_msgs/msg/Image topic, e.g. a live camera's)")
    add_run_options(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    source_bag = Path(args.bag)
    rig_text = read_custom_data(source_bag).get("vibro.rig_yaml")
    if not rig_text:
        raise RecordingError(f"{source_bag}: the bag holds no rig.yaml (metadata custom_data 'vibro.rig_yaml'); "
                             "it was not recorded by vibro graph")
    time_origin_ns = bag_time_origin_ns(source_bag)  # the replayed frames keep their stamps: the same clock
    frames_topic = frames_topic_of_bag(source_bag, args.frames_topic)
    if frames_topic != topics.FRAMES.name:
        print(f"replay: frames from {frames_topic}")
    out = Path(args.out) if args.out else source_bag.parent / f"{source_bag.name}.replay"
    if (out / REPLAY_BAG).resolve() == source_bag.resolve():
        raise RecordingError(f"{out}: the replay writes its own bag to {out / REPLAY_BAG}, which is the source bag; "
                             "choose another --out")
    foxglove = foxglove_parameters(args)
    prepare_output_dir(out, overwrite=args.overwrite, owned=REPLAY_OUTPUTS, command="replay", inputs=[source_bag])
    atomic_write_text(out / "rig.yaml", rig_text)
    write_recorded_calibration(out, rig_text, read_custom_data(source_bag))  # the lens calibration rig.yaml names
    bag = new_bag_path(out / REPLAY_BAG)
    env = prepare_environment(args.domain_id)
    with_accel = "accelerometers:" in rig_text
    t0 = time.monotonic()
    graph_run = GraphRun(timeout_s=args.timeout_s, env=env,
                         extra_params={"bag_source": {"bag": str(source_bag.resolve()), "frames_topic": frames_topic}},
                         respawn=args.respawn, namespace=args.namespace,
                         reference=lambda folder: reference_from_bag(
                             source_bag, folder / "reference_frame0.png", out / "rig.yaml", frames_topic))
    ok, summary, log_dir = execute_graph(out, bag, [BAG_SOURCE], with_accel=with_accel, run=graph_run,
                                         setup=RunSetup(base=args.params, time_origin_ns=time_origin_ns,
                                                        foxglove=foxglove))
    print(f"replay: {time.monotonic() - t0:.1f} s, logs in {log_dir}")
    print_summary(summary, bag)
    if ok:
        doc = document_from_bag(bag)
        doc.recording = str(source_bag)
        write_results(out / "results.json", doc)
        print(f"results: {out / 'results.json'}")
        if not doc.complete:
            print(f"vibro replay: error: the replayed run is incomplete ({doc.warnings[0]}); results.json is "
                  "marked \"complete\": false", file=sys.stderr)
            return 1
    return 0 if ok else 1
