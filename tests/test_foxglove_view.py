"""The Foxglove conversions and server of the foxglove_bridge node, without ROS: vibro_foxglove.view
turns the graph's messages (the real vibro_msgs/diagnostic_msgs classes, which import without rclpy) into
Foxglove payloads, decoded here as the Foxglove app decodes them (protobuf from the advertised schema, strict
JSON), and serves them on a real foxglove-sdk WebSocket server read by a real WebSocket client."""

from __future__ import annotations

import asyncio
import base64
import json
import math
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
from foxglove_client import SUBPROTOCOLS, capture, protobuf_class  # noqa: E402

from vibro_foxglove import view as fv  # noqa: E402

REPO = Path(__file__).resolve().parents[1]


def _decode(payload: fv.Payload):
    """A protobuf payload decoded with the schema its channel advertises (as the app does)."""
    from foxglove import messages

    spec = fv.CHANNELS_BY_TOPIC[payload.channel]
    schema = getattr(messages, spec.schema_name.split(".", 1)[1]).get_schema()
    cls = protobuf_class({"schemaName": schema.name, "schema": base64.b64encode(schema.data).decode()})
    return cls.FromString(payload.data)


def _strict_json(data: bytes):
    return json.loads(data, parse_constant=lambda name: (_ for _ in ()).throw(ValueError(name)))


def _stamped(msg, ns: int):
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(ns, 1_000_000_000)
    return msg


def test_the_core_imports_without_rclpy() -> None:
    code = ("import sys, vibro_foxglove.view as v; v.foxglove_layout(); "
            "assert 'rclpy' not in sys.modules, 'rclpy imported'")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert res.returncode == 0, res.stderr


@pytest.mark.parametrize("dtype, encoding", [(np.uint8, "mono8"), (np.uint16, "mono16")])
def test_a_frame_is_a_raw_image_with_its_pixels(dtype, encoding: str) -> None:
    rng = np.random.default_rng(1)
    pixels = rng.integers(0, np.iinfo(dtype).max, size=(7, 5), dtype=dtype)
    if dtype == np.uint16:
        pixels = pixels.astype(">u2")  # a big-endian camera buffer: Foxglove reads 16-bit little-endian
    stamp = 1_795_000_000_123_456_789
    img = _decode(fv.frame_payload(pixels, stamp))
    assert (img.width, img.height, img.encoding, img.step) == (5, 7, encoding, 5 * np.dtype(dtype).itemsize)
    assert img.timestamp.seconds * 10 ** 9 + img.timestamp.nanos == stamp
    got = np.frombuffer(img.data, dtype=np.dtype(dtype).newbyteorder("<")).reshape(7, 5)
    assert np.array_equal(got, pixels.astype(dtype))


def _geometry() -> fv.ImageGeometry:
    return fv.ImageGeometry(ball_roi=(56, 212, 48, 48), structure_roi=(8, 372, 144, 45), mm_per_px=0.06,
                            ball_diameter_mm=4.77, t0_s=0.25, fps=1000.0)


def _xy(points) -> list[float]:
    return [v for p in points for v in (p.x, p.y)]


def test_annotations_move_each_roi_up_by_its_displacement_in_pixels() -> None:
    from vibro_msgs.msg import DicFrame, ImpactEstimate

    g = _geometry()
    stamp = 1_795_000_000_000_000_000
    dic = DicFrame(frame_index=12, ball_mm=0.6, structure_mm=-0.12)  # 10 px up, 2 px down at 0.06 mm/px
    impact = ImpactEstimate(index=2, plate="top", cor=0.712)
    ann = _decode(fv.annotations_payload(dic, stamp, g, impact))
    structure, ball = ann.points
    assert _xy(ball.points) == pytest.approx([56, 202, 104, 202, 104, 250, 56, 250])
    assert _xy(structure.points) == pytest.approx([8, 374, 152, 374, 152, 419, 8, 419])
    (circle,) = ann.circles
    assert (circle.position.x, circle.position.y) == pytest.approx((80, 226))  # ROI centre 236 - 10 px
    assert circle.diameter == pytest.approx(4.77 / 0.06)
    assert all(a.timestamp.seconds * 10 ** 9 + a.timestamp.nanos == stamp for a in (ann.points[0], circle))
    (text,) = ann.texts
    assert "frame 12" in text.text and "+0.600 mm" in text.text and "COR 0.712" in text.text

    lost = _decode(fv.annotations_payload(DicFrame(frame_index=13, lost=True, ball_mm=math.nan,
                                                   structure_mm=math.nan, status="ZNCC 0.3 < 0.6"), stamp, g))
    assert not lost.circles and "lost: ZNCC 0.3 < 0.6" in lost.texts[0].text
    assert _xy(lost.points[1].points)[:2] == pytest.approx([56, 212])  # where the ROI started
    assert lost.points[1].outline_color.r == pytest.approx(1.0) and lost.points[1].outline_color.g < 0.2


def test_frame_index_of_a_stamp_follows_the_camera_clock() -> None:
    g = _geometry()
    assert [g.frame_index(g.t0_s + k / g.fps) for k in (0, 1, 999, 12345)] == [0, 1, 999, 12345]


def test_json_channels_are_strict_json_with_null_for_nan() -> None:
    from vibro_msgs.msg import DicFrame, ImpactEstimate

    ns = 1_795_000_000_250_000_000
    track = fv.track_payload(_stamped(DicFrame(frame_index=7, t_s=0.257, ball_mm=1.25, structure_mm=-0.5,
                                               ball_mean_zncc=0.99), ns))
    doc = _strict_json(track.data)
    assert track.log_time_ns == ns and doc["frame_index"] == 7 and doc["ball_mm"] == 1.25
    assert doc["ball_minus_structure_mm"] == 1.75 and doc["lost"] is False
    assert set(doc) == set(fv.TRACK.json_schema["properties"])
    lost = _strict_json(fv.track_payload(DicFrame(lost=True, ball_mm=math.nan, structure_mm=math.nan)).data)
    assert lost["ball_mm"] is None and lost["ball_minus_structure_mm"] is None  # JSON has no NaN
    impact = fv.impact_payload(_stamped(ImpactEstimate(index=4, plate="bottom", cor=0.7123456789012345,
                                                       cor_std=math.inf, final=True), ns))
    doc = _strict_json(impact.data)
    assert doc["cor"] == 0.7123456789012345 and doc["cor_std"] is None and doc["final"] is True
    assert impact.key == 4 and set(doc) == set(fv.IMPACTS.json_schema["properties"])


def test_diagnostics_keep_the_runs_namespace_and_numeric_values() -> None:
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

    array = DiagnosticArray(status=[
        DiagnosticStatus(name="/vibro_r1/dic_tracker", level=DiagnosticStatus.WARN, message="slow",
                         values=[KeyValue(key="rate_hz", value="512.5"), KeyValue(key="lag_s", value="nan"),
                                 KeyValue(key="url", value="ws://x:1")]),
        DiagnosticStatus(name="/vibro_r2/dic_tracker", level=DiagnosticStatus.OK)])
    (payload,) = fv.diagnostics_payloads(array, "/vibro_r1")
    doc = _strict_json(payload.data)
    assert doc["node"] == "dic_tracker" and doc["level"] == 1 and doc["level_name"] == "WARN"
    assert doc["values"] == {"rate_hz": 512.5, "lag_s": None, "url": "ws://x:1"}
    assert len(fv.diagnostics_payloads(array, "/")) == 2


def test_frame_throttle_sends_at_most_the_rate_whatever_the_camera_rate() -> None:
    throttle = fv.FrameThrottle(15.0)
    sent = [k for k in range(1000) if throttle.allow(k * 1e-3)]  # 1000 frames/s for 1 s
    assert len(sent) == 15 and sent[0] == 0  # slots at 0, 66.7, 133.3, ... ms: 15 in [0, 1 s)
    assert min(np.diff(sent)) >= 1000 / 15
    assert sum(fv.FrameThrottle(0.0).allow(k * 1e-3) for k in range(100)) == 100
    with pytest.raises(ValueError):
        fv.FrameThrottle(-1.0)


def test_the_shipped_layout_is_generated_and_refers_to_served_channels_and_fields() -> None:
    shipped = REPO / "src" / "vibro_bringup" / "config" / fv.LAYOUT_FILE_NAME
    assert shipped.read_text(encoding="utf-8") == fv.layout_text(), \
        "regenerate it: python -m vibro_foxglove.view"
    layout = json.loads(shipped.read_text())
    panels = layout["configById"]
    kinds = {k.split("!")[0] for k in panels}
    assert {"Image", "Plot", "Table"} <= kinds

    def ids(node):
        return [node] if isinstance(node, str) else ids(node["first"]) + ids(node["second"])

    assert sorted(ids(layout["layout"])) == sorted(panels)  # every panel placed once
    image = panels["Image!vibro"]["imageMode"]
    assert image["imageTopic"] == fv.FRAMES.topic and fv.ANNOTATIONS.topic in image["annotations"]
    paths = [p["value"] for c in panels.values() for p in c.get("paths", [])]
    paths += [c["topicPath"] for c in panels.values() if "topicPath" in c]
    assert f"{fv.TRACK.topic}.ball_mm" in paths and f"{fv.TRACK.topic}.structure_mm" in paths
    assert any(p.startswith(fv.IMPACTS.topic) and p.endswith(".cor") for p in paths)
    for path in paths:  # /topic{filter}.field...: topic served, field in its JSON schema
        topic = next(t for t in fv.CHANNELS_BY_TOPIC if path == t or path.startswith((t + ".", t + "{")))
        rest = path[len(topic):]
        field = rest.rsplit("}", 1)[-1].lstrip(".").split(".")[0]
        assert not field or field in fv.CHANNELS_BY_TOPIC[topic].json_schema["properties"], path


# ------------------------------------------------------------------------------------------- the server
def _impact(index: int, cor: float, final: bool):
    from vibro_msgs.msg import ImpactEstimate

    return _stamped(ImpactEstimate(index=index, plate="top", cor=cor, final=final), 1_795_000_000_000_000_000 + index)


def test_a_client_that_subscribes_late_gets_every_latched_result_but_no_old_stream() -> None:
    from vibro_msgs.msg import DicFrame

    server = fv.FoxgloveServer("127.0.0.1", 0, [fv.IMPACTS.topic, fv.TRACK.topic])
    try:
        for msg in (_impact(0, 0.61, False), _impact(1, 0.62, False), _impact(0, 0.65, True)):
            server.publish(fv.impact_payload(msg))  # before any client: the final replaces the streamed 0
        server.publish(fv.track_payload(DicFrame(frame_index=1, ball_mm=0.1)))
        got = []

        async def client():
            task = asyncio.ensure_future(capture(f"ws://127.0.0.1:{server.port}", connect_timeout_s=10,
                                                 stop=lambda: True, quiet_s=1.0, timeout_s=20))
            for _ in range(60):  # the owner's timer: replay to clients that subscribed since
                await asyncio.sleep(0.05)
                server.replay_pending()
            return await task

        cap = asyncio.run(client())
        got = [_strict_json(m.payload) for m in cap.on(fv.IMPACTS.topic)]
    finally:
        server.close()
    assert cap.subprotocol in SUBPROTOCOLS
    assert {c["topic"] for c in cap.channels.values()} == {fv.IMPACTS.topic, fv.TRACK.topic}
    assert sorted((d["index"], d["cor"], d["final"]) for d in got) == [(0, 0.65, True), (1, 0.62, False)]
    assert not cap.on(fv.TRACK.topic)  # the stream is live only


def test_a_client_that_stops_reading_never_blocks_publishing() -> None:
    """A Foxglove app on a slow link: it subscribes, then reads nothing. Publishing 2000 frames of 256 KiB
    (500 MiB, far beyond what TCP buffers hold) must return (a blocked publish never would); the SDK drops the
    stalled client's oldest messages (backlog 64) instead of waiting for it, so it gets only some."""
    import websockets.asyncio.client as wsc

    frame = np.zeros((512, 512), dtype=np.uint8)
    payload = fv.frame_payload(frame, 1)
    n = 2000

    def publish_all(server) -> float:
        t0 = time.perf_counter()
        for _ in range(n):
            server.publish(payload)
        return time.perf_counter() - t0

    server = fv.FoxgloveServer("127.0.0.1", 0, [fv.FRAMES.topic], backlog=64)
    try:
        alone_s = publish_all(server)

        async def stalled() -> tuple[float, int]:
            ws = await wsc.connect(f"ws://127.0.0.1:{server.port}", subprotocols=SUBPROTOCOLS, max_size=None,
                                   proxy=None, max_queue=1)
            await ws.recv()  # serverInfo
            adv = json.loads(await ws.recv())
            await ws.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": 1,
                                                                            "channelId": adv["channels"][0]["id"]}]}))
            await asyncio.sleep(0.5)
            # the client reads nothing meanwhile; a publish that waited for it would never return
            took = await asyncio.wait_for(asyncio.to_thread(publish_all, server), timeout=60)
            received = 0
            try:
                while True:
                    msg = await asyncio.wait_for(ws.recv(), timeout=2.0)
                    received += isinstance(msg, bytes) and msg[0] == 1
            except (asyncio.TimeoutError, Exception):
                pass
            await ws.close()
            return took, received

        with_client_s, received = asyncio.run(stalled())
    finally:
        server.close()
    print(f"2000 x 256 KiB frames: {alone_s:.3f} s with no client, {with_client_s:.3f} s with a stalled one; "
          f"it received {received}")
    assert 0 < received < n  # it got some, the rest was dropped for it rather than waited for


# ------------------------------------------------------------------------------------------- graph wiring
def test_the_bridge_joins_the_node_table_as_nobodys_reader(tiny_recording: Path, tmp_path: Path) -> None:
    from vibro_bringup.graph_spec import RunSetup, launch_nodes

    plain = {n.spec.name: n for n in launch_nodes(tiny_recording, tmp_path / "bag", reference_dir=tmp_path)}
    watched = {n.spec.name: n for n in launch_nodes(tiny_recording, tmp_path / "bag", reference_dir=tmp_path,
                                                    setup=RunSetup(foxglove={"port": 9001, "host": "127.0.0.1"}))}
    assert "foxglove_bridge" not in plain and set(watched) == set(plain) | {"foxglove_bridge"}
    bridge = watched.pop("foxglove_bridge")
    assert bridge.parameters["port"] == 9001 and bridge.parameters["host"] == "127.0.0.1"
    assert bridge.parameters["exit_when_done"] is True and bridge.parameters["rig_file"].endswith("rig.yaml")
    assert not bridge.respawn and bridge.respawn_on_failure
    # every other node is started exactly as without the bridge: nobody waits for it or its end
    def without_clock(nodes: dict) -> dict:  # the lab clock's origin is "now" for this rig: differs per call
        return {k: {p: v for p, v in n.parameters.items() if p != "time_origin_unix_ns"} for k, n in nodes.items()}

    assert without_clock(watched) == without_clock(plain)
    live = {n.spec.name: n for n in launch_nodes(tiny_recording, None, live=True, camera_topic="/camera/image_raw",
                                                 setup=RunSetup(foxglove={"port": 9001, "host": "0.0.0.0"}))}
    bridge = live["foxglove_bridge"]
    assert bridge.respawn and bridge.parameters["exit_when_done"] is False  # stays up with a live graph
    assert bridge.remappings == (("vibro/frames", "/camera/image_raw"),)  # watches the camera the tracker reads


def test_a_busy_port_is_refused_in_one_line_before_anything_starts(tiny_recording: Path, tmp_path: Path) -> None:
    with socket_listening() as port:
        res = subprocess.run([sys.executable, "-m", "vibro_app.cli", "graph", str(tiny_recording), "--bag",
                              str(tmp_path / "bag"), "--foxglove-port", str(port), "--foxglove-host", "127.0.0.1"],
                             capture_output=True, text=True, timeout=120)
    assert res.returncode == 2 and "Traceback" not in res.stderr, res.stderr
    assert res.stderr.strip().splitlines() == [
        f"vibro graph: error: --foxglove-port {port} --foxglove-host 127.0.0.1: cannot serve there "
        "(Address already in use); choose another port"]
    assert not (tmp_path / "bag").exists() and "run " not in res.stdout


class socket_listening:
    """A TCP port held open on 127.0.0.1 (as another server would)."""

    def __enter__(self) -> int:
        import socket

        self.sock = socket.socket()
        self.sock.bind(("127.0.0.1", 0))
        self.sock.listen()
        return self.sock.getsockname()[1]

    def __exit__(self, *exc) -> None:
        self.sock.close()
