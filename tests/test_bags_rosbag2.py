"""Bags as rosbag2 (Jazzy) writes them, QoS that hears every publisher, a killed recorder's bag reindexed.

Real processes over DDS (tests/bags_peer.py publishes with a chosen QoS), bags read back
with rosbags' and mcap's own readers.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml
from bag_polling import readable
from mcap.reader import make_reader

HERE = Path(__file__).resolve().parent
PEER = [sys.executable, str(HERE / "bags_peer.py")]
VIBRO = [sys.executable, "-m", "vibro_app.cli"]


def _popen(argv: list[str]) -> subprocess.Popen:
    return subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _wait_for(predicate, seconds: float) -> bool:
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        if predicate():
            return True
        time.sleep(0.1)
    return False


def _stop(*procs: subprocess.Popen) -> None:
    for proc in procs:
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
    for proc in procs:
        proc.communicate(timeout=30)


@pytest.mark.parametrize("subscriber_first", [True, False])
def test_results_subscription_hears_transient_local_history_and_volatile_publishers(
        subscriber_first: bool, ros_domain: str) -> None:
    """One reader, two publishers of vibro/status in other processes: transient local (5 kept as history,
    then one every 0.2 s) and volatile. rmw's BEST_AVAILABLE picks transient local in a fresh process
    and rejects the volatile one; results_subscription must get all history, the volatile publisher's
    messages, and every message once."""
    tl = PEER + ["pub", "--durability", "transient_local", "--depth", "100", "--tag", "tl", "--seconds", "9"]
    vol = PEER + ["pub", "--durability", "volatile", "--tag", "vol", "--seconds", "9"]
    sub_argv = PEER + ["sub", "--seconds", "7"]
    if subscriber_first:
        sub = _popen(sub_argv)
        assert sub.stdout.readline().strip() == "READY"
        pubs = [_popen(tl), _popen(vol)]
    else:
        pubs = [_popen(tl), _popen(vol)]
        time.sleep(2.0)  # both publishing before the reader exists: the history is all that is left of tl 0-4
        sub = _popen(sub_argv)
    out, err = sub.communicate(timeout=60)
    _stop(*pubs)
    assert sub.returncode == 0, err
    got = json.loads(out.strip().splitlines()[-1])
    tags = [tuple(x) for x in got]
    assert len(tags) == len(set(tags)), "a message was delivered twice"
    tl_n = sorted(n for t, n in tags if t == "tl")
    vol_n = sorted(n for t, n in tags if t == "vol")
    assert tl_n[:5] == [0, 1, 2, 3, 4]  # the transient-local history, whichever started first
    # the volatile publisher sends every 0.2 s; the reader hears it within its 0.5 s poll plus discovery
    assert len(vol_n) >= 5, vol_n
    # and keeps hearing the transient-local one live: 7 s of 0.2 s steps, minus start-up
    assert len(tl_n) >= 15, tl_n


def test_recorder_writes_rosbag2_names_and_offered_qos_and_records_a_best_effort_camera(
        tmp_path: Path, ros_domain: str) -> None:
    from rosbags.highlevel import AnyReader
    from rosbags.interfaces import QosDurability, QosHistory, QosReliability
    from rosbags.rosbag2 import Reader
    from rosbags.rosbag2.metadata import parse_qos

    bag = tmp_path / "lab"
    ns = ["--ros-args", "-r", "__ns:=/lab1"]
    recorder = _popen([sys.executable, "-m", "vibro_ros.recorder_node", *ns, "-p", f"bag:={bag}"])
    try:
        assert _wait_for(lambda: (bag / "metadata.yaml").exists(), 30)
        time.sleep(1.5)  # the recorder's subscriptions are created after metadata.yaml
        # vibro's status publisher profile (results: reliable, transient local, depth 5000) and a camera
        # driver's best-effort, depth-5 image stream, both in the namespace
        status = _popen(PEER + ["pub", "--durability", "transient_local", "--depth", "5000", "--tag", "s",
                                "--burst", "3", "--seconds", "6", *ns])
        camera = _popen(PEER + ["pub", "--type", "image", "--reliability", "best_effort", "--depth", "5",
                                "--tag", "cam", "--burst", "0", "--seconds", "5", "--node", "camera_driver", *ns])
        cam_out, _ = camera.communicate(timeout=60)
        status.communicate(timeout=60)
        time.sleep(0.5)
    finally:
        if recorder.poll() is None:
            recorder.send_signal(signal.SIGINT)
        _, recorder_err = recorder.communicate(timeout=30)
    assert recorder.returncode == 0
    # the best-effort camera is heard by the companion reader as designed: no rmw warning that its QoS is
    # incompatible with the first, reliable reader (a lab user reads that as "the camera is not recorded")
    assert "incompatible" not in recorder_err.lower(), recorder_err
    sent_frames = json.loads(cam_out.strip().splitlines()[-1])["published"]

    with Reader(bag) as reader:  # rosbags' rosbag2 reader: metadata.yaml
        conns = {c.topic: c for c in reader.connections}
    assert {"/lab1/vibro/status", "/lab1/vibro/frames"} <= set(conns)
    (st,) = conns["/lab1/vibro/status"].ext.offered_qos_profiles
    assert (st.reliability, st.durability, st.history, st.depth) == (
        QosReliability.RELIABLE, QosDurability.TRANSIENT_LOCAL, QosHistory.KEEP_LAST, 5000)
    (cam,) = conns["/lab1/vibro/frames"].ext.offered_qos_profiles
    # DDS discovery does not carry history/depth: a foreign publisher's are unknown, as rosbag2 records them
    assert (cam.reliability, cam.durability, cam.history, cam.depth) == (
        QosReliability.BEST_EFFORT, QosDurability.VOLATILE, QosHistory.UNKNOWN, 0)

    with open(next(bag.glob("*.mcap")), "rb") as handle:
        mreader = make_reader(handle)
        channels = {c.topic: c for c in mreader.get_summary().channels.values()}
        records = [m for m in mreader.iter_metadata() if m.name == "rosbag2"]
    for topic, expect in (("/lab1/vibro/status", st), ("/lab1/vibro/frames", cam)):
        assert parse_qos(channels[topic].metadata["offered_qos_profiles"]) == [expect]
        assert channels[topic].metadata["topic_type_hash"].startswith("RIHS01_")
    (record,) = records
    info = yaml.safe_load(record.metadata["serialized_metadata"])
    assert info["version"] == 9 and info["storage_identifier"] == "mcap"
    assert {t["topic_metadata"]["name"] for t in info["topics_with_message_count"]} == set(conns)

    with AnyReader([bag]) as reader:
        frames = [reader.deserialize(raw, c.msgtype) for c, _, raw in reader.messages()
                  if c.topic == "/lab1/vibro/frames"]
    # the old reliable-only recorder got none. Frames sent before the recorder discovered the camera and matched it
    # with a best-effort companion reader are gone (how many depends on the machine's load); from the first
    # recorded one on, every frame to the last is recorded (stamp.sec = the camera's frame number)
    assert len(frames) >= 3 and all(f.header.frame_id == "cam" for f in frames), (len(frames), sent_frames)
    numbers = sorted(f.header.stamp.sec for f in frames)
    assert numbers == list(range(numbers[0], sent_frames)), (numbers, sent_frames)


def test_killed_recorder_bag_is_read_then_reindexed_for_rosbags_and_mcap(tiny_recording: Path, tmp_path: Path,
                                                                         ros_domain: str) -> None:
    from rosbags.highlevel import AnyReader

    from vibro_ros.bags import read_messages

    bag = tmp_path / "killed"
    recorder = _popen([sys.executable, "-m", "vibro_ros.recorder_node", "--ros-args", "-p", f"bag:={bag}",
                       "-p", "chunk_kb:=1", "-p", "rig_file:=" + str(tiny_recording / "rig.yaml")])
    try:
        assert _wait_for(lambda: (bag / "metadata.yaml").exists(), 30)
        time.sleep(1.0)
        # 250 accelerometer samples in blocks of 1 sample: 250 reliable, transient-local messages
        src = subprocess.run([sys.executable, "-m", "vibro_fit.accel_source_node", "--ros-args",
                              "-p", f"recording:={tiny_recording}", "-p", "block_s:=0.00002",
                              "-p", "readers:=[recorder]"],
                             capture_output=True, text=True, timeout=60)
        assert src.returncode == 0, src.stderr
        # the recorder finishes its chunk in progress once a second: wait until every block is readable from the
        # file as it is (not a fixed 2.5 s: a loaded machine's recorder is seconds behind), then kill it
        assert _wait_for(lambda: readable(bag, "vibro/accel") == 250, 60)
    finally:
        recorder.kill()  # SIGKILL: no summary, no index, no final metadata
        recorder.communicate(timeout=30)
    mcap_file = next(bag.glob("*.mcap"))
    with pytest.raises(Exception):  # noqa: B017 - whatever rosbags raises: it cannot open the cut bag
        with AnyReader([bag]) as reader:
            list(reader.messages())

    ours = [(m.recorded_topic, m.timestamp_ns, bytes(m.data)) for m in read_messages(bag)]
    accel = [m for m in ours if m[0] == "/vibro/accel"]
    assert len(accel) == 250  # all: the kill lost nothing that was written

    res = subprocess.run([*VIBRO, "bag", "reindex", str(bag)], capture_output=True, text=True, timeout=60)
    assert res.returncode == 0, res.stderr
    assert "/vibro/accel: 250" in res.stdout
    with AnyReader([bag]) as reader:
        via_rosbags = [(c.topic, t, bytes(raw)) for c, t, raw in reader.messages()]
    with open(mcap_file, "rb") as handle:
        via_mcap = [(ch.topic, m.log_time, bytes(m.data))
                    for _, ch, m in make_reader(handle).iter_messages(log_time_order=False)]
    assert sorted(via_rosbags) == sorted(via_mcap) == sorted(ours)
    meta = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert meta["message_count"] == len(ours)
    assert {t["topic_metadata"]["name"]: t["message_count"] for t in meta["topics_with_message_count"]}[
        "/vibro/accel"] == 250
    assert "vibro.rig_yaml" in meta["custom_data"]  # carried over for vibro replay
    assert os.path.exists(str(mcap_file) + ".cut")


@pytest.fixture(scope="module")
def graph_bag(reference_run: dict) -> Path:
    """One real vibro graph run recorded by vibro's recorder (the shared ``reference_run``)."""
    return reference_run["bag"]


@pytest.mark.parametrize("prefix", ["/lab2/", ""], ids=["rosbag2-namespaced", "old-relative"])
def test_a_bag_written_by_rosbags_like_ros2_bag_record_gives_the_same_results(graph_bag: Path, tmp_path: Path,
                                                                            prefix: str) -> None:
    """Every message of the vibro-recorded bag copied by rosbags' own Writer (version 9, MCAP, cdr) under
    rosbag2's names in a namespace (/lab2/vibro/...), or under the relative names of vibro's old bags:
    vibro results must give exactly the original's results."""
    from rosbags.highlevel import AnyReader
    from rosbags.rosbag2 import StoragePlugin, Writer

    from vibro_ros.bags import make_typestore

    store = make_typestore()
    copy = tmp_path / "copy"
    with AnyReader([graph_bag]) as reader:
        assert all(c.topic.startswith("/") for c in reader.connections)  # vibro records fully qualified names
        writer = Writer(copy, version=9, storage_plugin=StoragePlugin.MCAP)
        with writer:
            conns = {}
            for c in reader.connections:
                # vibro graph runs in its own namespace (/vibro_<run id>/vibro/...): the copy keeps the vibro/ part;
                # /diagnostics is absolute in every namespace (ROS convention): a recorder keeps it as it is
                name = prefix + c.topic[c.topic.index("/vibro/") + 1:] if "/vibro/" in c.topic else c.topic
                conns[c.id] = writer.add_connection(name, c.msgtype, typestore=store,
                                                    offered_qos_profiles=c.ext.offered_qos_profiles)
            for c, t, raw in reader.messages():
                writer.write(conns[c.id], t, raw)
    from vibro_app.bag_results import results_from_bag  # what `vibro results` prints

    results = []
    for bag in (graph_bag, copy):
        doc = results_from_bag(bag)
        doc.pop("recording")
        results.append(doc)
    assert results[0]["impacts"], "the original run found no impacts"
    assert results[0] == results[1]
