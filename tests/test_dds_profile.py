"""vibro's Fast DDS writer profile (vibro_ros/fastdds_profile.xml): acknowledgements within 0.1 s instead
of Fast DDS's 3 s heartbeat, so a node's wait for its readers' acknowledgements at the end is short. Checked
here: the file is what Fast DDS reads (it parses it without an error, where a broken copy gets one), run_node's
helper points Fast DDS at it, and a lab's own profiles file or another RMW is left alone."""

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
