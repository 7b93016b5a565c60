"""Header stamps <-> seconds of the data clock (camera or DAQ time)."""

from __future__ import annotations

import pytest
from std_msgs.msg import Header

from vibro_ros.node_support import seconds_from_stamp, stamp_from_seconds


@pytest.mark.parametrize("t_s", [0.0, 0.25, 0.25 + 1499 / 1000, 1 - 1e-10, 2.9999999996, -0.5, 1234.000000001])
def test_stamp_round_trips_to_the_nearest_nanosecond(t_s: float) -> None:
    header = stamp_from_seconds(Header(), t_s)
    assert 0 <= header.stamp.nanosec < 1_000_000_000
    assert abs(seconds_from_stamp(header) - t_s) <= 0.5e-9 + 1e-12 * abs(t_s)


def test_a_fraction_rounding_up_carries_into_the_seconds() -> None:
    # the old code gave 0 s 0 ns for 0.9999999999 s: an item stamped one second early
    header = stamp_from_seconds(Header(), 1 - 1e-10)
    assert (header.stamp.sec, header.stamp.nanosec) == (1, 0)


def test_frame_index_recovered_from_the_stamp_of_every_frame() -> None:
    # what dic_tracker does with an Image stamp: k = round((stamp - t0_s) * fps)
    t0_s, fps = 0.25, 1000.0
    for k in range(0, 200_000, 7):
        t = seconds_from_stamp(stamp_from_seconds(Header(), t0_s + k / fps))
        assert round((t - t0_s) * fps) == k
