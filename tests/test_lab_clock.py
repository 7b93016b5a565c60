"""The lab clock of header stamps: stamp = time_origin_unix_ns + data time, in integer nanoseconds."""

from __future__ import annotations

import time
from pathlib import Path

import pytest
from std_msgs.msg import Header

from vibro_io.rig import load_rig, parse_rig, write_rig
from vibro_model.errors import RigError
from vibro_ros.lab_clock import (
    BAG_TIME_ORIGIN_KEY,
    data_time_from_stamp_ns,
    origin_from_custom_data,
    run_time_origin_ns,
    stamp_ns_from_data_time,
    unix_s_to_ns,
)
from vibro_ros.node_support import seconds_from_stamp, stamp_from_seconds, stamp_ns

#: A wall-clock origin in 2027 (ns): a float Unix time this size only resolves 256 ns.
ORIGIN_NS = 1_800_000_000_123_456_789


def test_integer_round_trip_of_microsecond_data_times_over_ten_seconds() -> None:
    # data times 0..10 s at 1 us steps (every step of the first and last 50 ms, every 1013th between: the
    # test stays fast): the stamp is origin + exactly k us, and the data time read back stamps to the same
    # integer again (a float Unix time would be off by up to 128 ns)
    steps = [*range(0, 50_001), *range(50_001, 9_950_000, 1013), *range(9_950_000, 10_000_001)]
    for k in steps:
        t_s = k * 1e-6
        stamp = stamp_ns_from_data_time(ORIGIN_NS, t_s)
        assert stamp == ORIGIN_NS + 1000 * k
        back = data_time_from_stamp_ns(ORIGIN_NS, stamp)
        assert abs(back - t_s) <= 0.5e-9
        assert stamp_ns_from_data_time(ORIGIN_NS, back) == stamp


@pytest.mark.parametrize("t_s", [0.0, 0.25, 0.25 + 1499 / 1000, 1 - 1e-10, 2.9999999996, 3599.123456789])
def test_header_stamp_is_the_origin_plus_the_data_time(t_s: float) -> None:
    header = stamp_from_seconds(Header(), t_s, ORIGIN_NS)
    assert 0 <= header.stamp.nanosec < 1_000_000_000
    assert header.stamp.sec >= 1_800_000_000  # wall clock, not 1970
    assert abs(stamp_ns(header) - (ORIGIN_NS + t_s * 1e9)) <= 1.0
    assert abs(seconds_from_stamp(header, ORIGIN_NS) - t_s) <= 0.5e-9 + 1e-12 * t_s


def test_frame_index_recovered_from_wall_clock_stamps() -> None:
    # what dic_tracker does with an Image stamp: k = round((stamp - origin - t0_s) * fps)
    t0_s, fps = 0.25, 1000.0
    for k in range(0, 200_000, 7):
        t = seconds_from_stamp(stamp_from_seconds(Header(), t0_s + k / fps, ORIGIN_NS), ORIGIN_NS)
        assert round((t - t0_s) * fps) == k


def test_origin_zero_keeps_stamps_on_the_data_clock() -> None:
    header = stamp_from_seconds(Header(), 1.5)
    assert (header.stamp.sec, header.stamp.nanosec) == (1, 500_000_000)


def test_unix_seconds_convert_exactly_to_the_written_digits() -> None:
    assert unix_s_to_ns(1718000000.123456) == 1_718_000_000_123_456_000
    assert unix_s_to_ns(1718000000) == 1_718_000_000_000_000_000
    # the float's binary value would give ...123456001 or ...123455999: not what was written
    assert unix_s_to_ns(1718000000.000001) == 1_718_000_000_000_001_000


def test_run_origin_puts_frame_0_at_the_given_or_current_wall_time() -> None:
    assert run_time_origin_ns(0.25, 1718000000.5) == 1_718_000_000_250_000_000
    before = time.time_ns()
    origin = run_time_origin_ns(0.0)
    assert before <= origin <= time.time_ns()


def test_bag_metadata_origin() -> None:
    assert origin_from_custom_data({}, "bag") == 0  # a bag recorded before: stamps were data time
    assert origin_from_custom_data({BAG_TIME_ORIGIN_KEY: str(ORIGIN_NS)}, "bag") == ORIGIN_NS
    for bad in ("1.8e18", "-5", "soon"):
        with pytest.raises(ValueError, match=f"bag: metadata custom_data '{BAG_TIME_ORIGIN_KEY}'"):
            origin_from_custom_data({BAG_TIME_ORIGIN_KEY: bad}, "bag")


def _rig_dict() -> dict:
    return {
        "camera": {"fps": 1000.0, "t0_s": 0.0, "mm_per_px": 0.05},
        "ball": {"mass_kg": 0.01, "diameter_mm": 10.0, "youngs_modulus_pa": 2e11, "poisson_ratio": 0.3},
        "structure": {"gap_mm": 12.0, "mass_kg": 1.0, "youngs_modulus_pa": 2e11, "poisson_ratio": 0.3},
        "excitation": {"frequency_hz": 20.0},
        "dic": {"subset_px": 21, "mesh_step_px": 10, "ball_roi": [0, 0, 40, 40], "structure_roi": [50, 0, 40, 40]},
    }


def test_rig_start_time_is_optional_and_validated(tmp_path: Path) -> None:
    data = _rig_dict()
    assert parse_rig(data).camera.start_time_unix_s is None
    data["camera"]["start_time_unix_s"] = 1718000000.123456
    rig = parse_rig(data)
    assert rig.camera.start_time_unix_s == 1718000000.123456
    write_rig(rig, tmp_path / "rig.yaml")  # round trip through the file
    assert load_rig(tmp_path / "rig.yaml").camera.start_time_unix_s == 1718000000.123456
    for bad, why in ((1718000000123, "between 2000-01-01 and tomorrow"),  # milliseconds
                     (12.5, "between 2000-01-01 and tomorrow"),           # a camera clock
                     (time.time() + 3 * 86400, "between 2000-01-01 and tomorrow"),
                     ("2024-06-10", r"\(a number"), (True, r"\(a number"), (float("nan"), r"\(a number")):
        data["camera"]["start_time_unix_s"] = bad
        with pytest.raises(RigError, match=f"rig.yaml: key 'camera.start_time_unix_s': expected a Unix time in "
                                           f"seconds {why}"):
            parse_rig(data)


def test_node_time_origin_parameter(ros_domain: str) -> None:
    import rclpy

    from vibro_model.errors import RecordingError
    from vibro_ros.node_support import time_origin_parameter

    rclpy.init()
    try:
        node = rclpy.create_node("clock_probe", parameter_overrides=[
            rclpy.parameter.Parameter("time_origin_unix_ns", value=ORIGIN_NS)])
        assert time_origin_parameter(node) == ORIGIN_NS
        node.destroy_node()
        node = rclpy.create_node("clock_probe_default")
        assert time_origin_parameter(node) == 0
        node.destroy_node()
        node = rclpy.create_node("clock_probe_bad", parameter_overrides=[
            rclpy.parameter.Parameter("time_origin_unix_ns", value=-1)])
        with pytest.raises(RecordingError, match="'time_origin_unix_ns' must be >= 0"):
            time_origin_parameter(node)
        node.destroy_node()
    finally:
        rclpy.shutdown()


def test_describe_origin_names_utc() -> None:
    from vibro_bringup.graph_runner import describe_origin

    assert describe_origin(1_718_000_000_123_456_789) == (
        "header stamps = 2024-06-10T06:13:20.123456789 UTC + camera time (time_origin_unix_ns 1718000000123456789)")
    assert "data time" in describe_origin(0)
