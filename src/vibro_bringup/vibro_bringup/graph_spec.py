"""The vibro node graph, defined once: used by ``vibro graph`` here and by the launch file on a lab PC."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Iterable

import yaml

from vibro_io.rig import load_rig
from vibro_model.errors import RecordingError
from vibro_ros import topics as T
from vibro_ros.lab_clock import TIME_ORIGIN_PARAMETER, origin_from_custom_data, run_time_origin_ns

#: The in-process node ``vibro graph`` watches the graph with; a declared reader of every node there.
MONITOR = "vibro_graph_monitor"
#: The topics the monitor subscribes to (graph_runner.Monitor).
MONITOR_SUBSCRIBES = (T.STATUS.name, T.DIC.name, T.IMPACTS.name, T.SIMULATION.name, T.DISCREPANCY.name,
                      T.ACCEL.name, T.ACCEL_IMPACTS.name)


@dataclass(frozen=True, kw_only=True)
class NodeSpec:
    """One node: ``ros2 run <package> <executable>`` on a lab PC, ``python -m <module>`` here.

    ``publishes``/``subscribes``: topic names (vibro/status and /diagnostics, which every node
    publishes, are implied); ``waits_for``: nodes whose end-of-stream status on vibro/status it
    needs although it reads none of their data. The declared readers of a node
    (:func:`readers_of`) come from these lists.
    """

    name: str
    package: str
    executable: str
    module: str
    role: str  # "source" (ends with its input), "processing", "sink" or "viewer" (see VIEWER)
    publishes: tuple[str, ...] = ()
    subscribes: tuple[str, ...] = ()
    waits_for: tuple[str, ...] = field(default=())


_RESULTS = (T.STRUCTURE.name, T.FLIGHTS.name, T.IMPACTS.name)
#: Role of a node that only watches (the Foxglove bridge): nobody's declared reader or writer, so no node waits
#: for it or for its end; vibro graph does not wait for it to finish and stops it once the graph has ended.
VIEWER = "viewer"
NODES: tuple[NodeSpec, ...] = (
    NodeSpec(name="recorder", package="vibro_ros", executable="recorder", module="vibro_ros.recorder_node", role="sink",
             subscribes=tuple(t.name for t in T.ALL_TOPICS)),
    NodeSpec(name="dic_tracker", package="vibro_dic", executable="dic_tracker", module="vibro_dic.dic_tracker_node",
             role="processing",
             publishes=(T.DIC.name,), subscribes=(T.FRAMES.name, T.STATUS.name)),
    NodeSpec(name="impact_detector", package="vibro_fit", executable="impact_detector",
             module="vibro_fit.impact_detector_node", role="processing",
             publishes=(T.ACCEL_IMPACTS.name,), subscribes=(T.ACCEL.name, T.STATUS.name)),
    NodeSpec(name="trajectory_fitter", package="vibro_fit", executable="trajectory_fitter",
             module="vibro_fit.trajectory_fitter_node", role="processing",
             publishes=_RESULTS, subscribes=(T.DIC.name, T.ACCEL.name, T.STATUS.name)),
    NodeSpec(name="simulator", package="vibro_sim", executable="simulator", module="vibro_sim.simulator_node",
             role="processing",
             publishes=(T.SIMULATION.name,), subscribes=(*_RESULTS, T.DIC.name, T.STATUS.name)),
    NodeSpec(name="discrepancy", package="vibro_discrepancy", executable="discrepancy",
             module="vibro_discrepancy.discrepancy_node", role="processing",
             publishes=(T.DISCREPANCY.name, T.IMPACTS_FINAL_MODEL.name),
             subscribes=(*_RESULTS, T.DIC.name, T.STATUS.name),
             waits_for=("simulator",)),
    NodeSpec(name="frame_source", package="vibro_dic", executable="frame_source", module="vibro_dic.frame_source_node",
             role="source",
             publishes=(T.FRAMES.name,), subscribes=(T.DIC.name,)),
    NodeSpec(name="accel_source", package="vibro_fit", executable="accel_source", module="vibro_fit.accel_source_node",
             role="source",
             publishes=(T.ACCEL.name,)),
    NodeSpec(name="foxglove_bridge", package="vibro_foxglove", executable="foxglove_bridge",
             module="vibro_foxglove.bridge_node", role=VIEWER,
             subscribes=(T.FRAMES.name, T.DIC.name, *_RESULTS, T.SIMULATION.name, T.DISCREPANCY.name,
                         T.IMPACTS_FINAL_MODEL.name, T.DIAGNOSTICS.name)),
)

#: Replaces frame_source and accel_source when a recorded bag is replayed (``vibro replay``).
BAG_SOURCE = NodeSpec(name="bag_source", package="vibro_ros", executable="bag_source",
                      module="vibro_ros.bag_source_node", role="source",
                      publishes=(T.FRAMES.name, T.ACCEL.name), subscribes=(T.DIC.name,))

ALL_SPECS: dict[str, NodeSpec] = {s.name: s for s in (*NODES, BAG_SOURCE)}


#: nodes that act once, at the end of a run (the simulation and the discrepancy need the whole run's final
#: fits): a live stream has no end, so a live graph leaves them out. They would only hold every DicFrame in
#: memory (3.6 million an hour at 1000 frames/s) and cost each frame about 0.2 ms of CPU; a live session is
#: simulated once it has ended (``vibro replay`` of its bag).
END_OF_RUN_NODES = ("simulator", "discrepancy")


def graph_nodes(*, bag: bool, with_accel: bool, live: bool = False, replay: bool = False,
                foxglove: bool = False) -> list[NodeSpec]:
    """The nodes of one run, in start order (sink, processing, sources): the recorder only when a bag
    is recorded, impact_detector and accel_source only with accelerometers, no file source and none of
    :data:`END_OF_RUN_NODES` when live (a camera driver publishes the frames, and the stream has no end),
    bag_source instead of the file sources for a replay, the Foxglove bridge only with ``foxglove``."""
    out = []
    for spec in NODES:
        if live and spec.name in END_OF_RUN_NODES:
            continue
        if spec.name == "recorder" and not bag:
            continue
        if spec.role == VIEWER and not foxglove:
            continue
        if spec.name in ("impact_detector", "accel_source") and not with_accel:
            continue
        if spec.role == "source" and (replay or live):  # live: a camera and a DAQ driver publish instead
            continue
        out.append(spec)
    if replay:
        out.append(BAG_SOURCE)
    return out


def _reads(reader: NodeSpec, writer: NodeSpec) -> bool:
    """``reader`` takes data from ``writer``: a topic it publishes, or its end-of-stream status (a sink
    records every status; other nodes only the statuses of what they read, and of ``waits_for``). A viewer
    reads from nobody and nobody from it: no node waits for it."""
    if VIEWER in (reader.role, writer.role):
        return False
    subs = set(reader.subscribes) - ({T.STATUS.name} if reader.role != "sink" else set())
    return bool((set(writer.publishes) | {T.STATUS.name}) & subs) or writer.name in reader.waits_for


#: End-of-stream status (vibro/status ``stream``) each stateful processing node announces when it is done.
FINAL_STREAM = {"dic_tracker": "dic", "impact_detector": "accel_impacts", "trajectory_fitter": "impacts",
                "simulator": "simulation", "discrepancy": "discrepancy"}


def status_streams(spec: NodeSpec) -> set[str]:
    """The vibro/status streams node ``spec`` announces the end of: its data topics' last name components."""
    return T.status_streams(spec.publishes)


def history_kept_until(name: str, present: Iterable[str]) -> list[str]:
    """The final streams of node ``name``'s stateful readers among ``present``: it stays up until all of them
    have ended, so that a reader restarted mid-run still finds what it needs from it (the latched histories
    of vibro/dic and vibro/accel, the latched results and end-of-stream statuses of the other nodes)."""
    return sorted(FINAL_STREAM[n] for n in readers_of(name, present) if n in FINAL_STREAM)


def readers_of(name: str, present: Iterable[str]) -> list[str]:
    """The declared readers of node ``name`` among the nodes ``present``."""
    return sorted(n for n in set(present) if n != name and _reads(ALL_SPECS[n], ALL_SPECS[name]))


#: topics a node does not subscribe to in a run without accelerometers (trajectory_fitter with
#: use_accelerometers false): a source that publishes them anyway (a replay's bag_source) must not wait for it there
UNREAD_WITHOUT_ACCEL = {"trajectory_fitter": (T.ACCEL.name,)}


def reader_topics_of(name: str, readers: Iterable[str], excluded: Iterable[str] = (),
                     unread: dict[str, Iterable[str]] | None = None) -> list[str]:
    """``reader=topic`` pairs for node ``name``'s parameter ``reader_topics``: each of ``readers`` must be matched on
    every topic of ``name`` (its data topics and vibro/status) that it subscribes to (the monitor: MONITOR_SUBSCRIBES;
    the recorder: all but its ``excluded`` topics; any reader: not the topics ``unread`` lists for it in this run,
    e.g. :data:`UNREAD_WITHOUT_ACCEL`). /diagnostics is not waited for."""
    published = set(ALL_SPECS[name].publishes) | {T.STATUS.name}
    unread = unread or {}
    pairs = []
    for reader in sorted(set(readers)):
        if reader == MONITOR:
            subscribed = set(MONITOR_SUBSCRIBES)
        elif reader in ALL_SPECS:
            subscribed = set(ALL_SPECS[reader].subscribes)
            if ALL_SPECS[reader].role == "sink":  # as the recorder takes exclude_topics: relative or qualified
                subscribed = {t for t in subscribed if not any(x == t or x.endswith("/" + t) for x in excluded)}
        else:
            continue  # a reader the table does not know: matched on any topic
        subscribed -= set(unread.get(reader, ()))
        pairs += [f"{reader}={topic}" for topic in sorted(published & subscribed)]
    return pairs


def writers_of(name: str, present: Iterable[str]) -> list[str]:
    """The nodes among ``present`` that node ``name`` takes data from."""
    return sorted(n for n in set(present) if n != name and _reads(ALL_SPECS[name], ALL_SPECS[n]))


#: Params-file key prefix matching a node name in any namespace (rcl's ``/**`` wildcard), so a
#: graph started under ``-r __ns:=/lab1`` still gets its parameters.
ANY_NAMESPACE = "/**/"


def params_file_key(node_name: str) -> str:
    """The params-file key of ``node_name`` in any namespace: ``/**/<node_name>``."""
    return ANY_NAMESPACE + node_name


def node_name_of_key(key: str, source: str | Path = "params file") -> str:
    """The node name of a params-file key (``/**/name``, or a bare ``name``/``/name``);
    RecordingError naming ``source`` for keys this graph cannot map to one of its nodes."""
    name = key[len(ANY_NAMESPACE):] if key.startswith(ANY_NAMESPACE) else key.removeprefix("/")
    if not name.isidentifier():
        raise RecordingError(f"{source}: key {key!r}: expected /**/<node name> (e.g. /**/dic_tracker)")
    return name


def default_params_file() -> Path:
    """config/vibro.yaml of the source tree, else of the installed package's share/ folder."""
    here = Path(__file__).resolve().parents[1] / "config" / "vibro.yaml"
    if here.is_file():
        return here
    from ament_index_python.packages import get_package_share_directory

    return Path(get_package_share_directory("vibro_bringup")) / "config" / "vibro.yaml"


def foxglove_layout_file() -> Path:
    """config/vibro.foxglove-layout.json (the Foxglove layout for the bridge's channels) of the source tree, else
    of the installed package's share/ folder."""
    return default_params_file().parent / "vibro.foxglove-layout.json"


def write_reference_frame(recording: str | Path, out_png: str | Path) -> Path | None:
    """Write frame 0 of ``recording`` (frames/ or video.avi) to ``out_png`` (lossless PNG, 8 or 16 bit).

    Returns the PNG path, or None when frame 0 cannot be read (the tracker then falls back
    to the first image it receives). The tracker uses it as its DIC reference, so a tracker
    restarted mid-run measures displacement since frame 0.
    """
    import cv2

    from vibro_io.frames import FrameSequence, find_frames_source

    rec = Path(recording)
    seq = FrameSequence(find_frames_source(rec), load_rig(rec / "rig.yaml").camera)
    first = next(iter(seq), None)
    if first is None or first.index != 0 or not first.ok:
        return None
    out_png = Path(out_png)
    if not cv2.imwrite(str(out_png), first.image):
        return None
    return out_png


def run_time_origin(rig_yaml: str | Path) -> int:
    """The lab-clock origin (ns since the Unix epoch) of a run on the recording of ``rig_yaml``: the wall time of
    data time 0, from ``camera.start_time_unix_s`` (wall time of frame 0) when rig.yaml gives it, else with
    frame 0 at the wall clock now (:func:`vibro_ros.lab_clock.run_time_origin_ns`)."""
    cam = load_rig(rig_yaml).camera
    return run_time_origin_ns(cam.t0_s, cam.start_time_unix_s)


def bag_time_origin_ns(bag: str | Path) -> int:
    """The lab-clock origin a bag's stamps are on (metadata custom_data ``vibro.time_origin_unix_ns``; 0 for a bag
    recorded without it, whose stamps are data time); RecordingError for a malformed value."""
    from vibro_ros.bags import read_custom_data

    try:
        return origin_from_custom_data(read_custom_data(bag), f"{bag}/metadata.yaml")
    except ValueError as exc:
        raise RecordingError(str(exc)) from None


IMAGE_TYPE = "sensor_msgs/msg/Image"


def frames_topic_of_bag(bag: str | Path, requested: str | None = None) -> str:
    """The bag topic holding the camera images to replay: ``requested`` (checked: recorded, as an Image), else
    ``vibro/frames`` (any namespace), else the bag's only Image topic (a live session's camera, e.g.
    ``/camera/image_raw``); RecordingError naming the Image topics when none or several could be meant."""
    from vibro_ros.bags import matching_name, recorded_topics

    recorded = recorded_topics(bag)
    images = sorted(name for name, kind in recorded.items() if kind == IMAGE_TYPE)
    if requested:
        if any(matching_name(name, {requested}) for name in images):
            return requested
        raise RecordingError(f"{bag}: no {IMAGE_TYPE} topic {requested} recorded; its image topics: "
                             f"{', '.join(images) or 'none'}")
    if any(matching_name(name, {T.FRAMES.name}) for name in images):
        return T.FRAMES.name
    if len(images) == 1:
        return images[0]
    if not images:
        raise RecordingError(f"{bag}: no camera images recorded (no {IMAGE_TYPE} topic): nothing to replay")
    raise RecordingError(f"{bag}: no {T.FRAMES.name} but several image topics ({', '.join(images)}): "
                         "choose one with --frames-topic")


def reference_from_bag(bag: str | Path, out_png: str | Path, rig_yaml: str | Path,
                       frames_topic: str = T.FRAMES.name) -> Path | None:
    """Write the image of frame 0 recorded on ``frames_topic`` (index from its stamp on the bag's lab clock and
    rig.yaml's camera) to ``out_png``; None when the bag holds no frame 0."""
    import cv2
    from rclpy.serialization import deserialize_message
    from sensor_msgs.msg import Image

    from vibro_dic.dic_tracker_node import image_array
    from vibro_ros.bags import read_messages
    from vibro_ros.node_support import seconds_from_stamp

    cam = load_rig(rig_yaml).camera
    origin_ns = bag_time_origin_ns(bag)
    for m in read_messages(bag, {frames_topic}):
        msg = deserialize_message(m.data, Image)
        if int(round((seconds_from_stamp(msg.header, origin_ns) - cam.t0_s) * cam.fps)) != 0:
            continue
        out_png = Path(out_png)
        return out_png if cv2.imwrite(str(out_png), image_array(msg)) else None
    return None


@dataclass(frozen=True, kw_only=True)
class RunSetup:
    """What every node of one run is given beside the node table's wiring.

    Attributes
    ----------
    base : str or Path or None
        The parameters YAML (``/**/<node>: ros__parameters: ...``); None: the installed config/vibro.yaml.
    reference_image : str or Path or None
        dic_tracker's ``reference_image`` (frame 0 as an image file); None: none given.
    time_origin_ns : int or None
        Every node's ``time_origin_unix_ns``: the lab clock of the header stamps (wall time of data time 0,
        ns); None: :func:`run_time_origin` of the recording's rig.yaml.
    foxglove : dict or None
        The Foxglove bridge's parameters (e.g. ``{"port": 8765}``) to run it too; None: no bridge.
    """

    base: str | Path | None = None
    reference_image: str | Path | None = None
    time_origin_ns: int | None = None
    foxglove: dict[str, Any] | None = None


DEFAULT_RUN_SETUP = RunSetup()


def node_parameters(recording: str | Path, bag: str | Path | None, setup: RunSetup = DEFAULT_RUN_SETUP,
                    with_accel: bool = True, *, nodes: Iterable[NodeSpec] | None = None,
                    extra_readers: Iterable[str] = (), live: bool = False) -> dict[str, dict[str, Any]]:
    """Parameters per node for one run: the defaults file (``setup.base``), then the recording and bag paths,
    every node's ``time_origin_unix_ns`` (``setup.time_origin_ns``, default :func:`run_time_origin`),
    ``setup.reference_image`` (frame 0 as an image file) for dic_tracker when given, and from the node table
    each node's declared ``readers`` (plus ``extra_readers``, e.g. vibro graph's monitor), the recorder's
    ``writers`` and ``exit_when_done`` (not ``live``). ``nodes``: the run's nodes (default
    :func:`graph_nodes` for ``bag`` and ``with_accel``, with the Foxglove bridge when ``setup.foxglove`` is
    given: its parameters, e.g. ``{"port": 8765}``)."""
    base, reference_image = setup.base, setup.reference_image
    time_origin_ns, foxglove = setup.time_origin_ns, setup.foxglove
    base = Path(base or default_params_file())
    data = yaml.safe_load(base.read_text(encoding="utf-8")) or {}
    params = {node_name_of_key(key, base): dict(block.get("ros__parameters", {})) for key, block in data.items()}
    rec = Path(recording).resolve()
    params.setdefault("frame_source", {})["recording"] = str(rec)
    params.setdefault("accel_source", {})["recording"] = str(rec)
    for name in ("dic_tracker", "trajectory_fitter", "simulator", "impact_detector", "discrepancy", "recorder"):
        params.setdefault(name, {})["rig_file"] = str(rec / "rig.yaml")
    params["trajectory_fitter"]["use_accelerometers"] = with_accel
    present = [s.name for s in (nodes if nodes is not None else graph_nodes(bag=bag is not None,
                                                                            with_accel=with_accel, live=live,
                                                                            foxglove=foxglove is not None))]
    if reference_image is not None:
        params["dic_tracker"]["reference_image"] = str(Path(reference_image).resolve())
    if reference_image is not None and "frame_source" in present:
        # from a recording's files: their frame count is the tracker's progress total (a replay's bag_source
        # announces its count when it ends, like a camera)
        from vibro_io.recording import open_recording

        params["dic_tracker"]["frames_expected"] = len(open_recording(rec).frames)
    if bag is not None:
        params.setdefault("recorder", {})["bag"] = str(Path(bag).resolve())
    if time_origin_ns is None:
        time_origin_ns = run_time_origin(rec / "rig.yaml")
    for name in present:
        p = params.setdefault(name, {})
        p[TIME_ORIGIN_PARAMETER] = int(time_origin_ns)
        if ALL_SPECS[name].role == VIEWER:  # nobody's reader or writer: only its own settings
            p["rig_file"] = str(rec / "rig.yaml")
            p["exit_when_done"] = not live
            p.update(foxglove or {})
            continue
        p["readers"] = readers_of(name, present) + sorted(set(extra_readers) - set(present))
        if ALL_SPECS[name].role != "sink":  # a sink's outputs are files: it has no reader to wait for
            excluded = [t for t in params.get("recorder", {}).get("exclude_topics", []) if t]
            p["reader_topics"] = reader_topics_of(name, p["readers"], excluded,
                                                  None if with_accel else UNREAD_WITHOUT_ACCEL) or [""]
        p["exit_when_done"] = not live
        p["keep_history_until"] = history_kept_until(name, present) or [""]
        if ALL_SPECS[name].role == "sink":
            p["writers"] = writers_of(name, present)
    for p in params.values():
        if not p.get("readers", True):
            p["readers"] = [""]  # ROS 2 parameter files cannot type an empty list
    return params


@dataclass(frozen=True)
class LaunchNode:
    """One node as ``ros2 launch`` starts it (``launch_ros.actions.Node``)."""

    spec: NodeSpec
    parameters: dict[str, Any]
    remappings: tuple[tuple[str, str], ...]
    respawn: bool            # live graph: processing nodes never end by themselves (exit_policy restarts them)
    respawn_on_failure: bool  # file mode: restart only after a crash (a node that finished exits 0)
    respawn_delay_s: float


#: live: the nodes that lower their priority (parameter cpu_nice) so that dic_tracker gets a core when it needs one
LIVE_YIELDING_NODES = ("trajectory_fitter", "impact_detector")
#: their nice increment: CFS then weighs them about 1/3 of the tracker (335 against 1024) when they contend
LIVE_NICE = 5


@dataclass(frozen=True, kw_only=True)
class LiveDaq:
    """A DAQ driver's live accelerometer stream (docs/live.md, *Live accelerometers*).

    Attributes
    ----------
    topic : str
        Its AccelBlock topic.
    rate_hz : float
        The DAQ's sample rate (Hz): a block at another is refused; 0 = the first block's.
    """

    topic: str
    rate_hz: float = 0.0


def launch_nodes(recording: str | Path, bag: str | Path | None, *, live: bool = False,
                 camera_topic: str = T.FRAMES.name, setup: RunSetup = DEFAULT_RUN_SETUP,
                 reference_dir: str | Path | None = None, respawn_delay_s: float = 2.0,
                 daq: LiveDaq | None = None) -> list[LaunchNode]:
    """What launch/vibro.launch.py starts: the same nodes, parameters and declared readers as ``vibro graph``
    (without its monitor). File mode: dic_tracker's reference is frame 0 written to ``reference_dir``
    (default: a new temporary folder) and every node exits once its stream has ended. What a node's exit
    means (restart after ``respawn_delay_s``, or end the run) is :func:`vibro_bringup.exit_policy.exit_verdict`'s
    call in the launch file's exit handlers, not launch's own ``respawn=True`` (which would restart a node
    that finished, or one that refused its input).
    ``setup`` (:class:`RunSetup`): the parameters file (``base``); ``foxglove``: the Foxglove bridge's parameters
    (e.g. ``{"port": 8765}``) to start it too (None: not started); from a recording it exits once the other nodes
    have gone, live it stays up and respawns. ``reference_image``: dic_tracker's reference (an image of frame 0)
    instead of the one written from the recording (live: instead of the first image received);
    ``time_origin_ns``: the lab-clock origin of the stamps (wall time of data time 0, ns; live: the camera's
    frame 0 minus t0_s) instead of :func:`run_time_origin`. ``daq`` (live): a DAQ driver's AccelBlock stream
    (:class:`LiveDaq`), read by impact_detector and trajectory_fitter with ``live_accel``."""
    from vibro_io.recording import open_recording

    rec = open_recording(recording)
    bag = str(bag) if bag else None
    # live, the recording only gives the rig: its accelerometer files are an old run's, which next to a live
    # camera would put that run's impacts into this one's flights; a live graph takes accelerometers only from a
    # DAQ driver (accel_topic)
    live_accel = bool(live and daq is not None and daq.topic)
    with_accel = live_accel or (rec.has_accel and not live)
    nodes = graph_nodes(bag=bag is not None, with_accel=with_accel, live=live, foxglove=setup.foxglove is not None)
    reference = Path(setup.reference_image) if setup.reference_image is not None else None
    if reference is None and not live:
        import tempfile

        folder = Path(reference_dir) if reference_dir is not None else Path(tempfile.mkdtemp(prefix="vibro-launch-"))
        reference = write_reference_frame(rec.path, folder / "reference_frame0.png")
    params = node_parameters(rec.path, bag, replace(setup, reference_image=reference), with_accel, nodes=nodes,
                             live=live)
    params["dic_tracker"]["live_camera"] = live
    if live:  # the buffered readers give way to the tracker, whose best-effort images are lost while it waits
        for name in LIVE_YIELDING_NODES:
            if name in params:
                params[name]["cpu_nice"] = LIVE_NICE
    remap = ((T.FRAMES.name, camera_topic),) if camera_topic != T.FRAMES.name else ()
    if live_accel:
        for name in ("impact_detector", "trajectory_fitter"):
            params[name]["live_accel"] = True
            params[name]["accel_rate_hz"] = float(daq.rate_hz)
        if daq.topic != T.ACCEL.name:
            remap += ((T.ACCEL.name, daq.topic),)
    restarted = ("processing", VIEWER)
    return [LaunchNode(spec, params.get(spec.name, {}), remap, live and spec.role in restarted,
                       not live and spec.role in restarted, respawn_delay_s) for spec in nodes]


class _QuotedStrings(yaml.SafeDumper):
    """Every string value single-quoted: rcl's params-file parser types an unquoted ``7983e209`` as a
    double and ``1234`` as an integer, whatever PyYAML meant."""


_QuotedStrings.add_representer(str, lambda dumper, text: dumper.represent_scalar("tag:yaml.org,2002:str", text,
                                                                                 style="'"))


def write_params_file(params: dict[str, dict[str, Any]], path: str | Path) -> Path:
    """Write a ROS 2 parameters YAML (``/**/node: ros__parameters: {...}``: applies in any namespace)."""
    path = Path(path)
    path.write_text(yaml.dump({params_file_key(n): {"ros__parameters": p} for n, p in params.items()},
                              Dumper=_QuotedStrings, sort_keys=False), encoding="utf-8")
    return path
