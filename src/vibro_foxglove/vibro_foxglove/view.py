"""What a Foxglove app shows of the vibro graph: the graph's messages as Foxglove channels (no rclpy).

The ``foxglove_bridge`` node (:mod:`vibro_foxglove.bridge_node`) is a thin adapter: it hands
the messages it receives to the functions here and publishes what they return on a Foxglove
WebSocket server (:class:`FoxgloveServer`, the foxglove-sdk package). Messages are read by
attribute only, so the ROS message classes and rosbags' deserialized messages both work.

Channels (Foxglove topic names, without the run's ROS namespace, so one layout fits every run):

- ``/vibro/frames`` foxglove.RawImage: camera frames (mono8/mono16, little-endian), decimated.
- ``/vibro/annotations`` foxglove.ImageAnnotations: for each frame sent, the ball and structure ROIs
  moved by their DIC displacement, the ball outline, and a line of text; same timestamp as the frame.
- ``/vibro/track`` JSON: every DicFrame's displacements (mm, + up) and quality, for plots.
- ``/vibro/impacts``, ``/vibro/impacts_final_model`` JSON: every impact estimate with its COR.
- ``/vibro/structure``, ``/vibro/flights``, ``/vibro/simulation`` (D per model, without the trajectories),
  ``/vibro/discrepancy`` JSON.
- ``/diagnostics`` JSON: one message per node status of the run's namespace, numeric values as numbers.

Timestamps (``log_time``) are the messages' header stamps: the lab clock (ns since the Unix epoch).
JSON never carries NaN (invalid JSON, which a Foxglove app cannot parse): a missing number is null.
Result channels are *latched*: the server keeps their latest message per item and sends them to a
client that subscribes later, so a Foxglove app opened mid-run still shows every COR so far.
"""

from __future__ import annotations

import json
import math
import threading
from collections import OrderedDict, deque
from dataclasses import dataclass
from typing import Any, Hashable, Iterable

import numpy as np

DEFAULT_PORT = 8765


@dataclass(frozen=True)
class ChannelSpec:
    """One Foxglove channel: its topic, schema name, encoding ("protobuf" well-known schema or "json"),
    the ROS topic it comes from (relative vibro topic name), and whether it is latched (results)."""

    topic: str
    schema_name: str
    encoding: str
    ros_topic: str
    latched: bool = False
    json_schema: dict | None = None
    description: str = ""


def _object_schema(title: str, properties: dict[str, str]) -> dict:
    """A JSON schema of a flat object; ``properties``: name -> "number", "integer", "string", "boolean",
    "object" or "array" (numbers may be null: NaN in the message)."""
    types = {"number": ["number", "null"], "integer": "integer", "string": "string", "boolean": "boolean",
             "object": "object", "array": "array"}
    return {"type": "object", "title": title, "properties": {k: {"type": types[v]} for k, v in properties.items()}}


_IMPACT_FIELDS = {"index": "integer", "t_s": "number", "t_std_s": "number", "plate": "string", "cor": "number",
                  "cor_std": "number", "v_ball_before_m_per_s": "number", "v_ball_after_m_per_s": "number",
                  "v_structure_m_per_s": "number", "flight_before": "integer", "flight_after": "integer",
                  "final": "boolean"}
_TRACK_FIELDS = {"frame_index": "integer", "t_s": "number", "ball_mm": "number", "structure_mm": "number",
                 "ball_minus_structure_mm": "number", "ball_valid_points": "integer", "ball_mesh_points": "integer",
                 "structure_valid_points": "integer", "structure_mesh_points": "integer", "ball_mean_zncc": "number",
                 "structure_mean_zncc": "number", "lost": "boolean", "status": "string"}
_STRUCTURE_FIELDS = {"amplitude_mm": "number", "frequency_hz": "number", "phase_rad": "number", "offset_mm": "number",
                     "amplitude_std_mm": "number", "frequency_std_hz": "number", "phase_std_rad": "number",
                     "offset_std_mm": "number", "rms_residual_mm": "number", "frames_used": "integer",
                     "ball_offset_mm": "number"}
_FLIGHT_FIELDS = {"index": "integer", "t_start_s": "number", "t_end_s": "number", "a_mm_per_s2": "number",
                  "b_mm_per_s": "number", "c_mm": "number", "direction": "string", "friction_n": "number",
                  "friction_std_n": "number", "rms_residual_mm": "number", "points_used": "integer",
                  "fitted": "boolean", "note": "string", "final": "boolean"}

FRAMES = ChannelSpec("/vibro/frames", "foxglove.RawImage", "protobuf", "vibro/frames",
                     description="camera frames, decimated to max_frame_rate_hz")
ANNOTATIONS = ChannelSpec("/vibro/annotations", "foxglove.ImageAnnotations", "protobuf", "vibro/dic",
                          description="ball and structure ROIs moved by their DIC displacement, per frame sent")
TRACK = ChannelSpec("/vibro/track", "vibro.Track", "json", "vibro/dic",
                    json_schema=_object_schema("vibro.Track", _TRACK_FIELDS),
                    description="every DicFrame: ball and structure displacement (mm, + up), quality")
IMPACTS = ChannelSpec("/vibro/impacts", "vibro.Impact", "json", "vibro/impacts", latched=True,
                      json_schema=_object_schema("vibro.Impact", _IMPACT_FIELDS),
                      description="impact estimates with COR (Eq. 16); final=true replaces a streamed one")
IMPACTS_FINAL_MODEL = ChannelSpec("/vibro/impacts_final_model", "vibro.Impact", "json", "vibro/impacts_final_model",
                                  latched=True, json_schema=_object_schema("vibro.Impact", _IMPACT_FIELDS),
                                  description="impacts re-measured under the discrepancy analysis' final model")
STRUCTURE = ChannelSpec("/vibro/structure", "vibro.Structure", "json", "vibro/structure", latched=True,
                        json_schema=_object_schema("vibro.Structure", _STRUCTURE_FIELDS),
                        description="fitted structure sine (Eq. 2, 13)")
FLIGHTS = ChannelSpec("/vibro/flights", "vibro.Flight", "json", "vibro/flights", latched=True,
                      json_schema=_object_schema("vibro.Flight", _FLIGHT_FIELDS),
                      description="fitted free flights (Eq. 3, 14) with friction (Eq. 17)")
SIMULATION = ChannelSpec("/vibro/simulation", "vibro.Simulation", "json", "vibro/simulation", latched=True,
                         json_schema=_object_schema("vibro.Simulation", {"model": "string", "deviation": "number",
                                                                         "deviation_percent": "number",
                                                                         "impacts": "integer"}),
                         description="deviation D (Eq. 18) per model")
DISCREPANCY = ChannelSpec("/vibro/discrepancy", "vibro.Finding", "json", "vibro/discrepancy", latched=True,
                          json_schema=_object_schema("vibro.Finding", {
                              "index": "integer", "effect": "string", "parameters": "object",
                              "parameter_std": "object", "where": "string", "deviation_before": "number",
                              "deviation_after": "number"}),
                          description="physics the baseline model left out")
DIAGNOSTICS = ChannelSpec("/diagnostics", "vibro.NodeStatus", "json", "/diagnostics",
                          json_schema=_object_schema("vibro.NodeStatus", {
                              "node": "string", "name": "string", "level": "integer", "level_name": "string",
                              "message": "string", "hardware_id": "string", "values": "object"}),
                          description="one message per node status of the run (values numeric where they are)")

CHANNELS: tuple[ChannelSpec, ...] = (FRAMES, ANNOTATIONS, TRACK, IMPACTS, IMPACTS_FINAL_MODEL, STRUCTURE, FLIGHTS,
                                     SIMULATION, DISCREPANCY, DIAGNOSTICS)
CHANNELS_BY_TOPIC = {c.topic: c for c in CHANNELS}


@dataclass(frozen=True)
class Payload:
    """One message for a Foxglove channel: encoded bytes, its log time (ns, lab clock) and, for a latched
    channel, the item it describes (a later payload with the same key replaces it for late clients)."""

    channel: str
    data: bytes
    log_time_ns: int
    key: Hashable | None = None


def finite_or_none(value: float) -> float | None:
    """``value`` as a float, None for NaN/inf (JSON has no NaN)."""
    value = float(value)
    return value if math.isfinite(value) else None


def _json_value(value: Any) -> Any:
    if value is None:
        return None
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return finite_or_none(value)
    if isinstance(value, str):
        return value
    if isinstance(value, dict):
        return {str(k): _json_value(v) for k, v in value.items()}
    if isinstance(value, (list, tuple, np.ndarray)):
        return [_json_value(v) for v in value]
    return str(value)


def json_bytes(document: dict) -> bytes:
    """Strict JSON (no NaN/Infinity: they become null) as UTF-8 bytes."""
    return json.dumps(_json_value(document), allow_nan=False, separators=(",", ":")).encode("utf-8")


def stamp_ns(header: Any) -> int:
    """``header.stamp`` as integer ns since the Unix epoch (lab clock)."""
    return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)


def _fields(msg: Any, names: Iterable[str]) -> dict[str, Any]:
    return {n: getattr(msg, n) for n in names}


# ---------------------------------------------------------------------------------------------- frames
def frame_payload(pixels: np.ndarray, stamp: int, frame_id: str = "camera") -> Payload:
    """A foxglove.RawImage of a mono8 (uint8) or mono16 (uint16) image, rows packed, 16-bit little-endian."""
    from foxglove.messages import RawImage

    if pixels.ndim != 2 or pixels.dtype.kind != "u" or pixels.dtype.itemsize not in (1, 2):
        raise ValueError(f"frame: expected a 2-D uint8 or uint16 image, got {pixels.dtype} {pixels.shape}")
    data = np.ascontiguousarray(pixels, dtype="<u2" if pixels.dtype.itemsize == 2 else np.uint8)
    encoding = "mono8" if data.itemsize == 1 else "mono16"
    height, width = pixels.shape
    msg = RawImage(timestamp=_timestamp(stamp), frame_id=frame_id, width=width, height=height, encoding=encoding,
                   step=width * data.itemsize, data=data.tobytes())
    return Payload(FRAMES.topic, msg.encode(), stamp)


def _timestamp(ns: int):
    from foxglove.messages import Timestamp

    sec, nsec = divmod(int(ns), 1_000_000_000)
    return Timestamp(sec, nsec)


class FrameThrottle:
    """Lets a frame through at most ``max_rate_hz`` times per second of wall time (0 = every frame), so the
    viewer's cost and bandwidth stay bounded whatever the camera's rate. The first frame always passes."""

    def __init__(self, max_rate_hz: float):
        if not max_rate_hz >= 0:
            raise ValueError(f"max_frame_rate_hz must be >= 0, got {max_rate_hz}")
        self.period_s = 1.0 / max_rate_hz if max_rate_hz > 0 else 0.0
        self._next_s = -math.inf

    def allow(self, now_s: float) -> bool:
        """True when a frame arriving at ``now_s`` (monotonic s) is to be sent."""
        if now_s < self._next_s:
            return False
        # the next slot is one period after this frame (not after the last slot): no burst after a pause
        self._next_s = now_s + self.period_s
        return True


# ---------------------------------------------------------------------------------------------- annotations
@dataclass(frozen=True)
class ImageGeometry:
    """Where the tracked bodies are in the image: rig.yaml's ROIs (x, y, w, h px, in frame 0) and scale."""

    ball_roi: tuple[int, int, int, int]
    structure_roi: tuple[int, int, int, int]
    mm_per_px: float
    ball_diameter_mm: float
    t0_s: float
    fps: float

    @classmethod
    def from_rig(cls, rig: Any) -> "ImageGeometry":
        """From a :class:`vibro_io.rig.RigConfig`."""
        return cls(tuple(rig.dic.ball_roi.as_list()), tuple(rig.dic.structure_roi.as_list()),
                   float(rig.camera.mm_per_px), float(rig.ball.diameter_mm), float(rig.camera.t0_s),
                   float(rig.camera.fps))

    def frame_index(self, data_time_s: float) -> int:
        """The frame number of camera time ``data_time_s`` (s): round((t - t0_s) * fps)."""
        return int(round((data_time_s - self.t0_s) * self.fps))

    def shifted_roi(self, roi: tuple[int, int, int, int], displacement_mm: float) -> list[tuple[float, float]]:
        """The corners (x, y px; top-left, top-right, bottom-right, bottom-left) of ``roi`` moved by
        ``displacement_mm`` (+ up, so rows decrease by displacement_mm / mm_per_px)."""
        x, y, w, h = roi
        dy = -float(displacement_mm) / self.mm_per_px
        return [(x, y + dy), (x + w, y + dy), (x + w, y + h + dy), (x, y + h + dy)]

    def ball_centre(self, ball_mm: float) -> tuple[float, float]:
        """The ball's centre (x, y px): the ball ROI's centre moved by ``ball_mm``."""
        x, y, w, h = self.ball_roi
        return (x + w / 2.0, y + h / 2.0 - float(ball_mm) / self.mm_per_px)


_BALL_COLOUR = dict(r=1.0, g=0.55, b=0.0, a=1.0)
_STRUCTURE_COLOUR = dict(r=0.2, g=0.6, b=1.0, a=1.0)
_LOST_COLOUR = dict(r=1.0, g=0.1, b=0.1, a=1.0)


def annotations_payload(dic: Any, stamp: int, geometry: ImageGeometry, last_impact: Any | None = None) -> Payload:
    """A foxglove.ImageAnnotations for the frame of DicFrame ``dic``, stamped ``stamp`` (the frame image's own
    stamp, so that a Foxglove Image panel draws it on that image): the ball and structure ROIs moved by their
    displacement (lost frame: the ROIs where they started, in red), the ball's outline, and one line of text
    (frame, displacements, the latest impact's COR)."""
    from foxglove.messages import (
        CircleAnnotation,
        Color,
        ImageAnnotations,
        Point2,
        PointsAnnotation,
        PointsAnnotationType,
        TextAnnotation,
    )

    ts = _timestamp(stamp)
    lost = bool(dic.lost) or not (math.isfinite(dic.ball_mm) and math.isfinite(dic.structure_mm))
    ball_mm, structure_mm = (0.0, 0.0) if lost else (float(dic.ball_mm), float(dic.structure_mm))
    boxes = []
    for roi, shift, colour in ((geometry.structure_roi, structure_mm, _STRUCTURE_COLOUR),
                               (geometry.ball_roi, ball_mm, _BALL_COLOUR)):
        boxes.append(PointsAnnotation(timestamp=ts, type=PointsAnnotationType.LineLoop, thickness=2.0,
                                      points=[Point2(x=x, y=y) for x, y in geometry.shifted_roi(roi, shift)],
                                      outline_color=Color(**(_LOST_COLOUR if lost else colour))))
    circles = []
    if not lost:
        cx, cy = geometry.ball_centre(ball_mm)
        circles.append(CircleAnnotation(timestamp=ts, position=Point2(x=cx, y=cy), thickness=1.5,
                                        diameter=geometry.ball_diameter_mm / geometry.mm_per_px,
                                        outline_color=Color(**_BALL_COLOUR)))
    if lost:
        text = f"frame {int(dic.frame_index)} lost: {dic.status or 'no displacement'}"
    else:
        text = f"frame {int(dic.frame_index)}  ball {ball_mm:+.3f} mm  structure {structure_mm:+.3f} mm"
    if last_impact is not None and math.isfinite(last_impact.cor):
        text += f"  | impact {int(last_impact.index)} ({last_impact.plate}) COR {last_impact.cor:.3f}"
    texts = [TextAnnotation(timestamp=ts, position=Point2(x=4.0, y=16.0), text=text, font_size=14.0,
                            text_color=Color(r=1.0, g=1.0, b=1.0, a=1.0),
                            background_color=Color(r=0.0, g=0.0, b=0.0, a=0.6))]
    msg = ImageAnnotations(timestamp=ts, points=boxes, circles=circles, texts=texts)
    return Payload(ANNOTATIONS.topic, msg.encode(), stamp)


# ---------------------------------------------------------------------------------------------- JSON channels
def track_payload(dic: Any) -> Payload:
    """/vibro/track: a DicFrame's fields, and ``ball_minus_structure_mm`` (the ball in the cavity)."""
    doc = _fields(dic, _TRACK_FIELDS.keys() - {"ball_minus_structure_mm"})
    doc["ball_minus_structure_mm"] = float(dic.ball_mm) - float(dic.structure_mm)
    return Payload(TRACK.topic, json_bytes(doc), stamp_ns(dic.header))


def impact_payload(msg: Any, channel: ChannelSpec = IMPACTS) -> Payload:
    """/vibro/impacts (or impacts_final_model): an ImpactEstimate; latched per impact index."""
    return Payload(channel.topic, json_bytes(_fields(msg, _IMPACT_FIELDS)), stamp_ns(msg.header), int(msg.index))


def structure_payload(msg: Any) -> Payload:
    """/vibro/structure: the fitted structure sine; latched (one)."""
    return Payload(STRUCTURE.topic, json_bytes(_fields(msg, _STRUCTURE_FIELDS)), stamp_ns(msg.header), 0)


def flight_payload(msg: Any) -> Payload:
    """/vibro/flights: a fitted free flight; latched per flight index."""
    return Payload(FLIGHTS.topic, json_bytes(_fields(msg, _FLIGHT_FIELDS)), stamp_ns(msg.header), int(msg.index))


def simulation_payload(msg: Any) -> Payload:
    """/vibro/simulation: a model's deviation D (fraction and %), without the trajectories; latched per model."""
    doc = {"model": msg.model, "deviation": msg.deviation, "deviation_percent": 100.0 * float(msg.deviation),
           "impacts": msg.impacts}
    return Payload(SIMULATION.topic, json_bytes(doc), stamp_ns(msg.header), str(msg.model))


def discrepancy_payload(msg: Any) -> Payload:
    """/vibro/discrepancy: a finding with its parameters by name; latched per finding index."""
    names = list(msg.parameter_names)
    doc = {"index": msg.index, "effect": msg.effect, "parameters": dict(zip(names, msg.parameter_values)),
           "parameter_std": dict(zip(names, msg.parameter_std)), "where": msg.where,
           "deviation_before": msg.deviation_before, "deviation_after": msg.deviation_after}
    return Payload(DISCREPANCY.topic, json_bytes(doc), stamp_ns(msg.header), int(msg.index))


_LEVEL_NAMES = {0: "OK", 1: "WARN", 2: "ERROR", 3: "STALE"}


def _number_or_text(text: str) -> float | str | None:
    try:
        return finite_or_none(float(text))
    except ValueError:
        return text


def diagnostics_payloads(array: Any, namespace: str = "/") -> list[Payload]:
    """/diagnostics: one message per status of a DiagnosticArray whose name is in ``namespace`` (the run's;
    "/" = all), with ``node`` (the last name component, for plot filters like ``{node=="dic_tracker"}``) and
    its values as numbers where they parse (``rate_hz``, ``lag_s``, counts)."""
    prefix = namespace.rstrip("/") + "/"
    out = []
    for status in array.status:
        name = str(status.name)
        if namespace not in ("", "/") and not name.startswith(prefix):
            continue
        level = int.from_bytes(status.level, "little") if isinstance(status.level, bytes) else int(status.level)
        doc = {"node": name.rsplit("/", 1)[-1], "name": name, "level": level,
               "level_name": _LEVEL_NAMES.get(level, str(level)), "message": status.message,
               "hardware_id": status.hardware_id,
               "values": {kv.key: _number_or_text(kv.value) for kv in status.values}}
        out.append(Payload(DIAGNOSTICS.topic, json_bytes(doc), stamp_ns(array.header)))
    return out


# ---------------------------------------------------------------------------------------------- server
def _schema(spec: ChannelSpec):
    import foxglove
    from foxglove import messages

    if spec.encoding == "protobuf":
        return getattr(messages, spec.schema_name.split(".", 1)[1]).get_schema()
    return foxglove.Schema(name=spec.schema_name, encoding="jsonschema", data=json.dumps(spec.json_schema).encode())


def _listener(pending: deque):
    """A foxglove-sdk server listener that notes (client id, channel topic) subscriptions for the latched
    replay. It runs on the server's own thread, so it only records; :meth:`FoxgloveServer.replay_pending`
    sends."""
    from foxglove.websocket import ServerListener

    class SubscriptionNotes(ServerListener):
        def on_subscribe(self, client, channel) -> None:
            pending.append((int(client.id), str(channel.topic)))

    return SubscriptionNotes()


class FoxgloveServer:
    """A read-only Foxglove WebSocket server (foxglove-sdk) with the vibro channels in ``topics``.

    :meth:`publish` never waits for a client: the SDK queues at most ``backlog`` messages per client and drops
    the oldest when a client does not keep up. Latched channels keep their latest payload per key; a client
    that subscribes gets them (:meth:`replay_pending`, called from the publishing thread).
    """

    def __init__(self, host: str, port: int, topics: Iterable[str] = tuple(CHANNELS_BY_TOPIC), name: str = "vibro",
                 backlog: int = 1024):
        import foxglove

        unknown = sorted(set(topics) - set(CHANNELS_BY_TOPIC))
        if unknown:
            raise ValueError(f"unknown Foxglove channels {unknown} (known: {', '.join(CHANNELS_BY_TOPIC)})")
        self._lock = threading.Lock()
        self._pending: deque = deque()
        self._latched: dict[str, OrderedDict] = {}
        self.context = foxglove.Context()  # its own channels: two servers in one process do not share topics
        self.channels = {}
        for topic in topics:
            spec = CHANNELS_BY_TOPIC[topic]
            self.channels[topic] = foxglove.Channel(spec.topic, schema=_schema(spec), message_encoding=spec.encoding,
                                                   context=self.context)
            if spec.latched:
                self._latched[topic] = OrderedDict()
        self.server = foxglove.start_server(name=name, host=host, port=int(port), message_backlog_size=int(backlog),
                                            server_listener=_listener(self._pending), context=self.context)
        self.host = host
        self.sent = 0

    @property
    def port(self) -> int:
        return int(self.server.port)

    def publish(self, payload: Payload) -> None:
        """Send ``payload`` to every subscribed client (a channel not served is skipped)."""
        channel = self.channels.get(payload.channel)
        if channel is None:
            return
        latched = self._latched.get(payload.channel)
        if latched is not None and payload.key is not None:
            with self._lock:
                latched.pop(payload.key, None)
                latched[payload.key] = payload
        channel.log(payload.data, log_time=payload.log_time_ns)
        self.sent += 1

    def replay_pending(self) -> int:
        """Send the latched payloads of each channel a client subscribed to since the last call, to that client
        only. Returns the number of payloads sent."""
        n = 0
        while self._pending:
            client_id, topic = self._pending.popleft()
            latched = self._latched.get(topic)
            if not latched:
                continue
            with self._lock:
                payloads = list(latched.values())
            for p in payloads:
                self.channels[topic].log(p.data, log_time=p.log_time_ns, sink_id=client_id)
                n += 1
        return n

    def close(self) -> None:
        self.server.stop()


def websocket_url(host: str, port: int) -> str:
    """The ws:// URL a Foxglove app opens (a wildcard host becomes this machine's name)."""
    import socket

    shown = socket.gethostname() if host in ("0.0.0.0", "::", "") else host
    return f"ws://{shown}:{int(port)}"


# ---------------------------------------------------------------------------------------------- layout
LAYOUT_FILE_NAME = "vibro.foxglove-layout.json"


def _panel_config(config: Any, title: str) -> dict:
    """A panel's config as the app stores it (the SDK's layout classes give the app's key names) and its title."""
    return {**json.loads(config.to_json()), "foxglovePanelTitle": title}


def foxglove_layout() -> dict:
    """The Foxglove layout for the bridge's channels (the app's "Import from file" format: configById + a
    mosaic of panel ids): the camera image with the ROI annotations; ball and structure displacement; COR per
    impact and plate; the impacts as a table; node health (rate, lag) and the diagnostics; D and findings."""
    import foxglove.layouts as fl

    def series(path: str, label: str) -> Any:
        return fl.PlotSeries(value=path, label=label, enabled=True, timestamp_method="receiveTime")

    config = {
        "Image!vibro": _panel_config(fl.ImageConfig(image_mode=fl.ImageModeConfig(
            image_topic=FRAMES.topic, synchronize=False,
            annotations={ANNOTATIONS.topic: fl.ImageAnnotationSettings(visible=True)})), "camera + DIC ROIs"),
        "Plot!displacement": _panel_config(fl.PlotConfig(paths=[
            series(f"{TRACK.topic}.ball_mm", "ball (mm, + up)"),
            series(f"{TRACK.topic}.structure_mm", "structure (mm, + up)"),
            series(f"{TRACK.topic}.ball_minus_structure_mm", "ball - structure (mm)")],
            show_legend=True, x_axis_val="timestamp", y_axis_label="mm"), "DIC displacement"),
        "Plot!cor": _panel_config(fl.PlotConfig(paths=[
            series(f'{IMPACTS.topic}{{plate=="top"}}.cor', "COR top plate"),
            series(f'{IMPACTS.topic}{{plate=="bottom"}}.cor', "COR bottom plate")],
            show_legend=True, x_axis_val="timestamp", min_y_value=0.0, max_y_value=1.0, y_axis_label="COR"),
            "COR per impact"),
        "Table!impacts": _panel_config(fl.TableConfig(topic_path=IMPACTS.topic), "impacts"),
        "Plot!health": _panel_config(fl.PlotConfig(paths=[
            series(f'{DIAGNOSTICS.topic}{{node=="dic_tracker"}}.values.lag_s', "dic_tracker lag (s)"),
            series(f'{DIAGNOSTICS.topic}{{node=="trajectory_fitter"}}.values.lag_s', "trajectory_fitter lag (s)")],
            show_legend=True, x_axis_val="timestamp", y_axis_label="s"), "lag behind the data clock"),
        "Table!diagnostics": _panel_config(fl.TableConfig(topic_path=DIAGNOSTICS.topic), "diagnostics (latest)"),
        "Table!simulation": _panel_config(fl.TableConfig(topic_path=SIMULATION.topic), "deviation D per model"),
        "RawMessages!findings": _panel_config(fl.RawMessagesConfig(topic_path=DISCREPANCY.topic), "findings"),
    }

    def split(direction: str, first: Any, second: Any, percent: float) -> dict:
        return {"direction": direction, "first": first, "second": second, "splitPercentage": percent}

    mosaic = split("row",
                   split("column", "Image!vibro", split("row", "Table!impacts", "Table!simulation", 60), 65),
                   split("column",
                         split("column", "Plot!displacement", "Plot!cor", 50),
                         split("row", split("column", "Plot!health", "Table!diagnostics", 50),
                               "RawMessages!findings", 60), 60),
                   50)
    return {"configById": config, "globalVariables": {}, "userNodes": {}, "playbackConfig": {"speed": 1.0},
            "layout": mosaic}


def layout_text() -> str:
    """:func:`foxglove_layout` as the shipped file's text (indented JSON, newline-terminated)."""
    return json.dumps(foxglove_layout(), indent=2) + "\n"


if __name__ == "__main__":  # python -m vibro_foxglove.view PATH: (re)write the shipped layout file
    import sys
    from pathlib import Path

    target = (Path(sys.argv[1]) if len(sys.argv) > 1
              else Path(__file__).resolve().parents[1] / "config" / LAYOUT_FILE_NAME)
    target.write_text(layout_text(), encoding="utf-8")
    print(f"wrote {target}")
