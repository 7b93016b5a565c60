"""Parameters from outside (-p, params files, launch) are checked by vibro, not left to rclpy's type errors,
which end a node with a crash trace (vibro_ros.node_support.declare)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from vibro_model.errors import RecordingError
from vibro_ros.node_support import parameter_of_type


@pytest.mark.parametrize("value,default,want", [
    (5, 0.5, 5.0),                       # end_wait_s:=5 means 5 s
    (None, [""], []),                    # readers:=[] reaches ROS with no type: the empty list
    ([], [""], []),
    (["a", "b"], [""], ["a", "b"]),
    (3, 32, 3),
    (True, False, True),
    ("icgn", "paper", "icgn"),
])
def test_values_of_the_right_kind_are_taken_as_the_defaults_type(value, default, want) -> None:
    got = parameter_of_type("node", "p", value, default)
    assert got == want and type(got) is type(want)


@pytest.mark.parametrize("value,default,expected", [
    ("abc", 0.5, "takes a double, got 'abc' (string)"),
    (1.5, 32, "takes an int, got 1.5 (double)"),
    (True, 32, "takes an int, got True (bool)"),
    (1, False, "takes a bool, got 1 (int)"),
    (123, "", "takes a string, got 123 (int) (quote a number"),
    ("x", [""], "takes a string[], got 'x' (string)"),
    ([1, 2], [""], "takes a string[], got [1, 2] (int[])"),
    (None, 0.5, "takes a double, got no value"),
])
def test_values_of_another_kind_are_refused_naming_node_parameter_and_value(value, default, expected) -> None:
    with pytest.raises(RecordingError) as err:
        parameter_of_type("dic_tracker", "p", value, default)
    assert str(err.value).startswith("dic_tracker: parameter 'p' ") and expected in str(err.value)


@pytest.mark.parametrize("module,args,what", [
    ("vibro_dic.dic_tracker_node", ["zncc_min:=abc"], "parameter 'zncc_min' takes a double, got 'abc' (string)"),
    ("vibro_fit.trajectory_fitter_node", ["use_accelerometers:=1"], "parameter 'use_accelerometers' takes a bool"),
    ("vibro_ros.recorder_node", ["exclude_topics:=[1, 2]"], "parameter 'exclude_topics' takes a string[]"),
])
def test_a_wrongly_typed_parameter_stops_a_node_with_one_line(tiny_recording: Path, ros_domain: str, module: str,
                                                             args: list[str], what: str) -> None:
    # before: rclpy's InvalidParameterTypeException / ParameterUninitializedException, a traceback and exit 1
    argv = [sys.executable, "-m", module, "--ros-args", "-p", f"rig_file:={tiny_recording / 'rig.yaml'}"]
    for a in args:
        argv += ["-p", a]
    res = subprocess.run(argv, capture_output=True, text=True, timeout=60)
    assert res.returncode == 2, res.stderr
    assert what in res.stderr and "Traceback" not in res.stderr


def test_an_empty_reader_list_means_no_readers(tiny_recording: Path, ros_domain: str) -> None:
    # readers:=[] (and an integer for a float parameter) used to end the node with a traceback; now the source
    # streams its frames to nobody and exits 0
    res = subprocess.run([sys.executable, "-m", "vibro_dic.frame_source_node", "--ros-args", "-p",
                          f"recording:={tiny_recording}", "-p", "readers:=[]", "-p", "linger_s:=0"],
                         capture_output=True, text=True, timeout=60)
    assert res.returncode == 0, res.stderr
    assert "Traceback" not in res.stderr
