"""`vibro graph --foxglove` watched live as a Foxglove app watches it: a WebSocket client (tests/foxglove_client.py)
connects while the graph runs, subscribes to every advertised channel and decodes what arrives; the decoded
frames, DIC track and COR are compared with the recording's own images and with the run's bag. A second client
subscribes to everything and never reads (a Foxglove app on a dead link): the graph must not notice it."""

from __future__ import annotations

import asyncio
import os
import re
import socket
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
from domains import private_domain

sys.path.insert(0, str(Path(__file__).resolve().parent))
from foxglove_client import SUBPROTOCOLS, capture, stalled_client  # noqa: E402

FRAMES = 200
#: the graph's own deadline (s): it stops its nodes and exits non-zero after it
GRAPH_TIMEOUT_S = 150


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def live_run(tmp_path_factory) -> dict:
    """One `vibro graph --foxglove` run on a 200-frame synthetic recording, watched by a reading client and a
    stalled one; the reading client's capture, the run's stdout and its bag."""
    from vibro_sim.synth import SynthConfig, synthesize

    tmp = tmp_path_factory.mktemp("foxglove")
    rec = tmp / "rec"
    synthesize(rec, SynthConfig(frames=FRAMES, seed=5), progress=False)
    port = _free_port()
    url = f"ws://127.0.0.1:{port}"
    env = dict(os.environ, ROS_DOMAIN_ID=private_domain(), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    t0 = time.monotonic()
    proc = subprocess.Popen([sys.executable, "-m", "vibro_app.cli", "graph", str(rec), "--bag", str(tmp / "bag"),
                             "--foxglove-port", str(port), "--foxglove-host", "127.0.0.1",
                             "--timeout-s", str(GRAPH_TIMEOUT_S)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    try:
        async def watch():
            stalled = asyncio.ensure_future(stalled_client(url, GRAPH_TIMEOUT_S + 20))
            cap = await capture(url, connect_timeout_s=60, stop=lambda: proc.poll() is not None,
                                timeout_s=GRAPH_TIMEOUT_S + 20)
            stalled.cancel()
            return cap

        cap = asyncio.run(watch())
        capture_ended_s = time.monotonic() - t0
        # the graph ends by itself, at the latest at its own timeout plus its nodes' stop grace (20 s)
        out, err = proc.communicate(timeout=max(1.0, GRAPH_TIMEOUT_S + 40 - capture_ended_s))
    except subprocess.TimeoutExpired:
        proc.kill()
        out, err = proc.communicate()
        pytest.fail(f"vibro graph outlived its own --timeout-s {GRAPH_TIMEOUT_S} by 40 s\n{out}{err}"
                    f"{_logs_tail(tmp / 'bag.logs')}")
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    elapsed = time.monotonic() - t0
    return {"rec": rec, "bag": tmp / "bag", "cap": cap, "stdout": out, "stderr": err, "code": proc.returncode,
            "port": port, "elapsed_s": elapsed, "capture_ended_s": capture_ended_s}


def _logs_tail(log_dir: Path, lines: int = 12) -> str:
    """The last lines of every node's log of the run (what a failed run's reader needs first)."""
    from vibro_bringup.supervisor import log_tail

    return "".join(f"\n--- {log.name} ---\n{log_tail(log, lines)}" for log in sorted(log_dir.glob("*.log")))


@pytest.fixture(scope="module")
def bag(live_run: dict) -> dict:
    """The run's own record: DicFrames by frame index, final ImpactEstimates by impact index."""
    from vibro_ros.bags import deserialize, make_typestore, read_messages

    store = make_typestore()
    dic, impacts = {}, {}
    for m in read_messages(live_run["bag"], {"vibro/dic", "vibro/impacts"}):
        msg = deserialize(m, store)
        if m.topic.endswith("vibro/dic"):
            dic[int(msg.frame_index)] = msg
        elif msg.final:
            impacts[int(msg.index)] = msg
    return {"dic": dic, "impacts": impacts}


def _origin_ns(stdout: str) -> int:
    return int(re.search(r"time_origin_unix_ns (\d+)", stdout).group(1))


def test_the_graph_runs_as_without_the_bridge_and_prints_the_url(live_run: dict) -> None:
    out = live_run["stdout"]
    print(f"graph with the bridge, a reading and a stalled client: {live_run['elapsed_s']:.1f} s "
          f"(the server closed the client's connection at {live_run['capture_ended_s']:.1f} s)")
    assert live_run["code"] == 0, out + live_run["stderr"] + _logs_tail(live_run["bag"].parent / "bag.logs")
    assert f"frames in {FRAMES} / tracked {FRAMES} / lost 0" in out, out
    assert f"foxglove: ws://127.0.0.1:{live_run['port']}" in out  # at the start and in the summary
    assert "MISSING" not in out and "FAILED" not in out
    log = (live_run["bag"].parent / "bag.logs" / "foxglove_bridge.log").read_text()
    assert "Traceback" not in log and f"ws://127.0.0.1:{live_run['port']}" in log
    cap = live_run["cap"]
    assert cap.subprotocol in SUBPROTOCOLS and cap.server_info.get("op") == "serverInfo"
    assert cap.closed_by_server  # the server went away with the graph


def test_frames_are_the_recordings_images(live_run: dict) -> None:
    from vibro_io.rig import load_rig

    cap = live_run["cap"]
    frames = cap.on("/vibro/frames")
    assert frames, "no frame image received"
    assert cap.channel("/vibro/frames")["schemaName"] == "foxglove.RawImage"
    cam = load_rig(live_run["rec"] / "rig.yaml").camera
    origin = _origin_ns(live_run["stdout"])
    for m in frames:
        img = cap.decode(m)
        index = int(round(((img.timestamp.seconds * 10 ** 9 + img.timestamp.nanos - origin) * 1e-9 - cam.t0_s)
                          * cam.fps))
        png = cv2.imread(str(live_run["rec"] / "frames" / f"{index:06d}.png"), cv2.IMREAD_UNCHANGED)
        assert (img.width, img.height, img.encoding, img.step) == (png.shape[1], png.shape[0], "mono8", png.shape[1])
        assert np.array_equal(np.frombuffer(img.data, np.uint8).reshape(png.shape), png), index
    # decimated: at most max_frame_rate_hz (15) frames per second of the run, and fewer than the recording's
    assert len(frames) < FRAMES and len(frames) <= 15 * live_run["elapsed_s"] + 1


def test_ball_track_and_annotations_are_the_dic_results(live_run: dict, bag: dict) -> None:
    from vibro_io.rig import load_rig

    cap = live_run["cap"]
    track = [cap.decode(m) for m in cap.on("/vibro/track")]
    assert len(track) >= 20, len(track)
    for t in track:
        d = bag["dic"][t["frame_index"]]
        assert t["ball_mm"] == d.ball_mm and t["structure_mm"] == d.structure_mm and t["t_s"] == d.t_s
    rig = load_rig(live_run["rec"] / "rig.yaml")
    x, y, w, h = rig.dic.ball_roi.as_list()
    origin = _origin_ns(live_run["stdout"])
    frame_stamps = {m.log_time_ns for m in cap.on("/vibro/frames")}
    annotated = 0
    for m in cap.on("/vibro/annotations"):
        ann = cap.decode(m)
        stamp = ann.points[0].timestamp.seconds * 10 ** 9 + ann.points[0].timestamp.nanos
        index = int(round(((stamp - origin) * 1e-9 - rig.camera.t0_s) * rig.camera.fps))
        ball_top_y = y - bag["dic"][index].ball_mm / rig.camera.mm_per_px  # + up = rows decrease
        assert ann.points[1].points[0].y == pytest.approx(ball_top_y, abs=1e-9)
        assert ann.points[1].points[0].x == x and ann.points[1].points[2].x == x + w
        annotated += stamp in frame_stamps  # drawn on an image the client has
    assert annotated >= 1


def test_every_final_impact_arrives_with_the_recorded_cor(live_run: dict, bag: dict) -> None:
    cap = live_run["cap"]
    final = {d["index"]: d for d in (cap.decode(m) for m in cap.on("/vibro/impacts")) if d["final"]}
    assert len(bag["impacts"]) >= 5
    assert sorted(final) == sorted(bag["impacts"])
    for index, d in final.items():
        assert 0.0 <= d["cor"] <= 1.0
        assert d["cor"] == pytest.approx(bag["impacts"][index].cor, abs=1e-12)
        assert d["plate"] == bag["impacts"][index].plate


def test_diagnostics_arrive_with_numeric_values(live_run: dict) -> None:
    cap = live_run["cap"]
    docs = [cap.decode(m) for m in cap.on("/diagnostics")]
    tracker = [d for d in docs if d["node"] == "dic_tracker"]
    assert tracker and all(isinstance(d["values"]["rate_hz"], float) for d in tracker)
    assert {d["name"].rsplit("/", 1)[0] for d in docs} == {tracker[0]["name"].rsplit("/", 1)[0]}  # this run only
