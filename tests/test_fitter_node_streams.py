"""trajectory_fitter's end-of-stream logic, driven in-process (its callbacks called directly, no DDS)."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest

from vibro_msgs.msg import AccelBlock, DicFrame, StreamStatus


@pytest.fixture
def fitter(tiny_recording: Path, ros_domain: str):
    import rclpy

    from vibro_fit.trajectory_fitter_node import TrajectoryFitter

    rclpy.init(args=["--ros-args", "-p", f"rig_file:={tiny_recording / 'rig.yaml'}", "-p", "stream_wait_s:=0.3"])
    node = TrajectoryFitter()
    yield node
    node.destroy_node()
    rclpy.shutdown()


def _feed_dic(node, n: int) -> None:
    for k in range(n):
        node._on_dic(DicFrame(frame_index=k, t_s=0.25 + k / 1000.0, ball_mm=0.0, structure_mm=0.0, lost=False))
    node._on_status(StreamStatus(stream="dic", items_sent=n, items_lost=0, finished=True))


def test_a_lost_accelerometer_end_status_is_waited_for_then_reported(fitter) -> None:
    # a source that exited cannot repeat its end-of-stream status: the fitter must not wait forever
    assert fitter.use_accel and fitter.rig.accelerometers is not None
    fitter._on_block(AccelBlock(block_index=0, t_start_s=0.0, sample_rate_hz=50_000.0,
                                upper_ms2=np.zeros(100).tolist(), lower_ms2=np.zeros(100).tolist()))
    _feed_dic(fitter, 5)
    assert not fitter._ready()  # within stream_wait_s: still waiting for the accelerometer status
    time.sleep(0.35)
    assert fitter._ready()
    assert "accelerometer end-of-stream status never arrived" in fitter.health.message


def test_blocks_still_arriving_keep_the_fitter_waiting(fitter) -> None:
    _feed_dic(fitter, 5)
    for i in range(4):  # real-time accelerometer playback: blocks keep coming after the DIC stream ended
        time.sleep(0.15)
        fitter._on_block(AccelBlock(block_index=i, t_start_s=0.002 * i, sample_rate_hz=50_000.0,
                                    upper_ms2=np.zeros(100).tolist(), lower_ms2=np.zeros(100).tolist()))
        assert not fitter._ready()
    fitter._on_status(StreamStatus(stream="accel", items_sent=4, items_lost=0, finished=True))
    assert fitter._ready()
