"""A stand-in for the part of the launch / launch_ros API that launch/vibro.launch.py uses, to run the launch
file's own functions here: the real launch is not on the package index (../shared/ros-from-pypi.md).

It records what the launch file builds (nodes with their parameters, event handlers and their callbacks) and
lets a test fire a process exit into a handler as launch would (``handler.on_exit(event, context)``). Only the
constructor signatures and attributes the launch file touches are modelled, as in launch 3.4 / launch_ros
0.26 (Jazzy); behaviour of the real launch itself (its shutdown, its exit code on an exception raised by a
handler) was checked by hand with the real packages and is described in docs/node-graph.md.
"""

from __future__ import annotations

import importlib.util
import sys
import types
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

LAUNCH_FILE = Path(__file__).resolve().parents[1] / "src" / "vibro_bringup" / "launch" / "vibro.launch.py"


@dataclass
class DeclareLaunchArgument:
    name: str
    default_value: str | None = None
    description: str = ""


@dataclass
class OpaqueFunction:
    function: Callable


@dataclass
class LogInfo:
    msg: str


@dataclass
class TimerAction:
    period: float
    actions: list


@dataclass
class OnProcessExit:
    target_action: Any
    on_exit: Callable


@dataclass
class RegisterEventHandler:
    event_handler: OnProcessExit


@dataclass
class Node:
    package: str
    executable: str
    name: str
    namespace: str | None = None
    parameters: list = field(default_factory=list)
    remappings: list = field(default_factory=list)
    output: str = "log"
    respawn: bool = False
    respawn_delay: float | None = None
    additional_env: dict | None = None     # ExecuteProcess' (Node's base class)


class LaunchDescription(list):
    pass


@dataclass
class LaunchConfiguration:
    name: str

    def perform(self, context: "Context") -> str:
        return context.launch_configurations[self.name]


@dataclass
class Context:
    launch_configurations: dict[str, str]
    is_shutdown: bool = False


@dataclass
class ProcessExited:
    returncode: int


def load_launch_file():
    """The launch file as a module, with this stand-in as its launch / launch_ros imports."""
    modules = {
        "launch": types.ModuleType("launch"),
        "launch.actions": types.ModuleType("launch.actions"),
        "launch.event_handlers": types.ModuleType("launch.event_handlers"),
        "launch.substitutions": types.ModuleType("launch.substitutions"),
        "launch_ros": types.ModuleType("launch_ros"),
        "launch_ros.actions": types.ModuleType("launch_ros.actions"),
    }
    modules["launch"].LaunchDescription = LaunchDescription
    for cls in (DeclareLaunchArgument, LogInfo, OpaqueFunction, RegisterEventHandler, TimerAction):
        setattr(modules["launch.actions"], cls.__name__, cls)
    modules["launch.event_handlers"].OnProcessExit = OnProcessExit
    modules["launch.substitutions"].LaunchConfiguration = LaunchConfiguration
    modules["launch_ros.actions"].Node = Node
    saved = {name: sys.modules.get(name) for name in modules}
    sys.modules.update(modules)
    try:
        spec = importlib.util.spec_from_file_location("vibro_launch_file", LAUNCH_FILE)
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
    finally:
        for name, old in saved.items():
            if old is None:
                sys.modules.pop(name, None)
            else:
                sys.modules[name] = old
    return module


def launch_arguments(module, **given: str) -> dict[str, str]:
    """The launch configurations of ``ros2 launch ... name:=value``: the declared defaults, then ``given``."""
    declared = {a.name: a.default_value for a in module.generate_launch_description()
                if isinstance(a, DeclareLaunchArgument)}
    unknown = set(given) - set(declared)
    assert not unknown, f"not declared by the launch file: {unknown}"
    return {**declared, **given}


def run_opaque(module, **given: str) -> list:
    """The actions the launch file's OpaqueFunction returns for these arguments."""
    context = Context(launch_arguments(module, **given))
    (opaque,) = [a for a in module.generate_launch_description() if isinstance(a, OpaqueFunction)]
    return opaque.function(context)


def nodes_and_handlers(actions: list) -> dict[str, tuple[Node, OnProcessExit]]:
    """node name -> (the Node action, its exit handler)."""
    nodes = [a for a in actions if isinstance(a, Node)]
    handlers = {id(a.event_handler.target_action): a.event_handler for a in actions
                if isinstance(a, RegisterEventHandler)}
    return {n.name: (n, handlers[id(n)]) for n in nodes}
