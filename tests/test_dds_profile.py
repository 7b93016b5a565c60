"""vibro's Fast DDS profile (vibro_ros/fastdds_profile.xml): acknowledgements within 0.1 s instead of Fast DDS's 3 s
heartbeat, so a node's wait for its readers' acknowledgements at the end is short, and discovery past 32
participants in one domain on one host. Checked here: the file is what Fast DDS reads (it parses it without an
error, where a broken copy gets one), 40 participants with it all find each other, run_node's helper points Fast
DDS at it, and a lab's own profiles file or another RMW is left alone."""

from __future__ import annotations

import os
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

from vibro_ros.dds_profile import PROFILE_FILE, use_vibro_dds_profile

NS = "{http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles}"

#: a node that publishes (reliable) once Fast DDS has loaded the default profiles file from the environment
PUBLISH = """
import rclpy
from std_msgs.msg import String
rclpy.init()
node = rclpy.create_node("profile_check")
node.create_publisher(String, "profile_check", 10).publish(String(data="x"))
node.destroy_node()
rclpy.shutdown()
"""


def test_the_profile_is_a_default_writer_profile_with_a_short_heartbeat() -> None:
    root = ET.parse(PROFILE_FILE).getroot()
    (writer,) = root.iter(f"{NS}data_writer")
    assert writer.get("is_default_profile") == "true"
    period = writer.find(f"{NS}times/{NS}heartbeatPeriod")
    seconds = int(period.find(f"{NS}sec").text) + int(period.find(f"{NS}nanosec").text) * 1e-9
    assert 0 < seconds <= 0.2  # against Fast DDS's default 3 s


def test_fast_dds_parses_the_profile_and_would_report_a_broken_one(tmp_path: Path, ros_domain: str) -> None:
    broken = tmp_path / "broken.xml"
    broken.write_text(PROFILE_FILE.read_text().replace("</heartbeatPeriod>", "</heartbeat>"))

    def run(profile: Path) -> str:
        env = {**os.environ, "FASTRTPS_DEFAULT_PROFILES_FILE": str(profile)}
        res = subprocess.run([sys.executable, "-c", PUBLISH], capture_output=True, text=True, env=env, timeout=60)
        assert res.returncode == 0, res.stderr
        return res.stdout + res.stderr

    assert "XMLPARSER" in run(broken)  # how Fast DDS reports a profiles file it cannot read
    assert "XMLPARSER" not in run(PROFILE_FILE), run(PROFILE_FILE)


def test_run_node_points_fast_dds_at_the_profile_unless_the_lab_has_its_own() -> None:
    env: dict[str, str] = {}
    assert (use_vibro_dds_profile(env) == str(PROFILE_FILE)
            and env["FASTRTPS_DEFAULT_PROFILES_FILE"] == str(PROFILE_FILE))
    assert Path(env["FASTRTPS_DEFAULT_PROFILES_FILE"]).is_file()
    for own in ({"FASTRTPS_DEFAULT_PROFILES_FILE": "/lab/dds.xml"}, {"FASTDDS_DEFAULT_PROFILES_FILE": "/lab/dds.xml"},
                {"RMW_IMPLEMENTATION": "rmw_cyclonedds_cpp"}):
        env = dict(own)
        assert use_vibro_dds_profile(env) is None and env == own
    env = {"RMW_IMPLEMENTATION": "rmw_fastrtps_cpp"}
    assert use_vibro_dds_profile(env) == str(PROFILE_FILE)


#: participants in one domain on this host, each an rclpy context (a DDS participant) of one process: more than Fast
#: DDS's default discovery range (32 participant ids, beyond which the last ones never found each other), fewer
#: than the profile's 120
MANY = 40
MANY_PARTICIPANTS = r"""
import sys, time, rclpy
from rclpy.context import Context
n, wait_s = int(sys.argv[1]), float(sys.argv[2])
contexts, nodes = [], []
for i in range(n):
    c = Context()
    rclpy.init(context=c)
    contexts.append(c)
    nodes.append(rclpy.create_node(f"p{i}", namespace="/vibro_many", context=c))
deadline = time.monotonic() + wait_s
while True:
    seen = [sum(1 for _, ns in node.get_node_names_and_namespaces() if ns == "/vibro_many") for node in nodes]
    if min(seen) >= n or time.monotonic() > deadline:
        break
    time.sleep(0.2)
print(sum(s >= n for s in seen), min(seen))
for node, c in zip(nodes, contexts):
    node.destroy_node()
    rclpy.shutdown(context=c)
"""


def test_the_profile_keeps_the_builtin_transports_and_widens_discovery() -> None:
    root = ET.parse(PROFILE_FILE).getroot()
    kinds = {d.find(f"{NS}transport_id").text: d for d in root.iter(f"{NS}transport_descriptor")}
    (participant,) = root.iter(f"{NS}participant")
    assert participant.get("is_default_profile") == "true"
    used = [t.text for t in participant.find(f"{NS}rtps/{NS}userTransports")]
    assert [kinds[t].find(f"{NS}type").text for t in used] == ["SHM", "UDPv4"]  # Fast DDS's own default pair
    assert participant.find(f"{NS}rtps/{NS}useBuiltinTransports").text == "false"
    udp = next(kinds[t] for t in used if kinds[t].find(f"{NS}type").text == "UDPv4")
    assert int(udp.find(f"{NS}maxInitialPeersRange").text) >= 3 * MANY


def test_forty_participants_in_one_domain_all_find_each_other(ros_domain: str) -> None:
    """Four vibro graph runs' worth of participants on one domain and host: with the profile every one sees all the
    others (without it the 8 with the highest ids saw only the 32 first, docs/node-graph.md)."""
    env = {**os.environ, "FASTRTPS_DEFAULT_PROFILES_FILE": str(PROFILE_FILE)}
    res = subprocess.run([sys.executable, "-c", MANY_PARTICIPANTS, str(MANY), "60"], capture_output=True, text=True,
                         env=env, timeout=180)
    assert res.returncode == 0, res.stderr[-2000:]
    seeing_all, fewest = map(int, res.stdout.split())
    assert (seeing_all, fewest) == (MANY, MANY), res.stdout
