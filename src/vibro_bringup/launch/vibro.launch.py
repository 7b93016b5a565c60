"""Launch the vibro graph on a lab PC (ROS 2 Jazzy with launch_ros).

    ros2 launch vibro_bringup vibro.launch.py recording:=/data/run1 bag:=/data/bags/run1
    ros2 launch vibro_bringup vibro.launch.py recording:=/data/run1                  # no bag (bag:=none)
    ros2 launch vibro_bringup vibro.launch.py recording:=/data/run1 bag:=/data/bags/run1 namespace:=lab1
    ros2 launch vibro_bringup vibro.launch.py recording:=/data/run1 camera_topic:=/camera/image_raw live:=true \
        reference_image:=/data/run1/frame0.png time_origin_unix_ns:=1764000000123456789
    ros2 launch vibro_bringup vibro.launch.py recording:=/data/run1 foxglove:=true   # + Foxglove server

Thin over vibro_bringup.graph_spec.launch_nodes, the node table `vibro graph` uses too (nodes,
parameters, declared readers, remappings); tests/test_launch_order.py starts what it returns
the way launch does, in shuffled order, and compares with `vibro graph`. The nodes wait for
their declared readers by name, so the start order does not matter. From a recording every
node exits once the stream has ended (launch then exits 0).

Every node's exit is judged by vibro_bringup.exit_policy.exit_verdict, the rule of `vibro graph`: a
processing node that crashes is restarted after `respawn_delay` (at most `respawn_max` times from a
recording; always live); a source or the recorder that dies, a node out of restarts, or any node that
refuses its input (exit code 2: bad parameters, another run's data) ends the whole launch at once, with
one error line naming the node and why, and exit code 1. Ctrl-C ends it with exit code 0.
Live (camera-only: the recording gives the rig.yaml), the simulator and the discrepancy node are left out
(they act once a run has ended, which a live stream never does: simulate a live session once it has ended:
vibro replay of its bag). foxglove:=true adds the Foxglove bridge (ws://<this PC>:<foxglove_port>, see
docs/live.md): from a recording it exits once the other nodes have gone; live it stays up with them.
"""

from pathlib import Path

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, LogInfo, OpaqueFunction, RegisterEventHandler, TimerAction
from launch.event_handlers import OnProcessExit
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

from vibro_bringup import launch_arguments as args
from vibro_bringup.exit_policy import END_RUN, RESTART, exit_verdict
from vibro_bringup.graph_spec import LiveDaq, RunSetup, launch_nodes
from vibro_io.rig import rig_checked_environment


class RunEnded(RuntimeError):
    """Raised from an exit handler: launch logs its one line, shuts every node down and exits with code 1."""


def _start(n, namespace, restarts_done: int, respawn_max: int, live: bool, env: dict):
    """The node, and a handler judging its exit (exit_policy): restart it after a delay, or end the run. ``env``:
    added to the node's environment (the rig.yaml whose warnings this launch said once, rig_checked_environment)."""
    node = Node(package=n.spec.package, executable=n.spec.executable, name=n.spec.name, namespace=namespace,
                parameters=[n.parameters], remappings=list(n.remappings), output="screen",
                additional_env=env)

    def on_exit(event, context):
        if context.is_shutdown:  # Ctrl-C, or the run already ending: nodes stopping is what was asked for
            return None
        verdict = exit_verdict(n.spec.name, n.spec.role, event.returncode, restarts_done=restarts_done,
                               respawn_max=respawn_max, live=live)
        if verdict.action == RESTART:
            return [LogInfo(msg=f"vibro: {verdict.reason} in {n.respawn_delay_s:g} s"),
                    TimerAction(period=n.respawn_delay_s,
                                actions=_start(n, namespace, restarts_done + 1, respawn_max, live, env))]
        if verdict.action == END_RUN:
            raise RunEnded(f"vibro: {verdict.reason}")
        return None

    return [RegisterEventHandler(OnProcessExit(target_action=node, on_exit=on_exit)), node]


def _nodes(context, *unused, **kwargs):
    value = lambda name: LaunchConfiguration(name).perform(context)  # noqa: E731
    live = args.flag("live", value("live"))
    foxglove = ({"port": int(value("foxglove_port")), "host": value("foxglove_host")}
                if args.flag("foxglove", value("foxglove")) else None)
    namespace = args.namespace(value("namespace"))
    respawn_max = int(value("respawn_max"))
    # the launch arguments are read (and refused) in this order
    recording, bag = value("recording"), args.bag_directory(value("bag"), value("record"))
    camera_topic, base = value("camera_topic"), args.params_file(value("params_file"))
    respawn_delay_s = float(value("respawn_delay"))
    setup = RunSetup(base=base, foxglove=foxglove, reference_image=args.reference_image(value("reference_image")),
                     time_origin_ns=args.time_origin_ns(value("time_origin_unix_ns")))
    accel_topic, accel_rate_hz = value("accel_topic") or None, float(value("accel_rate_hz"))
    nodes = launch_nodes(recording, bag, live=live, camera_topic=camera_topic, setup=setup,
                         respawn_delay_s=respawn_delay_s,
                         daq=LiveDaq(topic=accel_topic, rate_hz=accel_rate_hz) if accel_topic else None)
    # launch_nodes read the rig.yaml here and said its warnings once: the nodes say them at debug level only
    env = rig_checked_environment(Path(recording) / "rig.yaml")
    actions = []
    for n in nodes:
        actions += _start(n, namespace, 0, respawn_max, live, env)
    return actions


def generate_launch_description() -> LaunchDescription:
    return LaunchDescription([
        DeclareLaunchArgument("recording", description="recording directory (rig.yaml, frames/, accel.csv)"),
        DeclareLaunchArgument("bag", default_value="none",
                              description="new bag directory to record the run to (none: no recorder)"),
        DeclareLaunchArgument("record", default_value="true", description="false: record no bag, whatever bag says"),
        DeclareLaunchArgument("namespace", default_value="",
                              description="ROS namespace of every node and vibro topic (e.g. lab1; /diagnostics "
                                          "stays at the root)"),
        DeclareLaunchArgument("params_file", default_value="",
                              description="parameters YAML (/**/<node>: ros__parameters: ...) instead of the "
                                          "installed config/vibro.yaml"),
        DeclareLaunchArgument("camera_topic", default_value="vibro/frames",
                              description="image topic to track (remap to a camera driver's image_raw)"),
        DeclareLaunchArgument("live", default_value="false", description="true: frames come from a live camera"),
        DeclareLaunchArgument("accel_topic", default_value="",
                              description="live: a DAQ driver's AccelBlock topic (docs/live.md, Live accelerometers; "
                                          "empty: camera only)"),
        DeclareLaunchArgument("accel_rate_hz", default_value="0.0",
                              description="live: the DAQ's sample rate; a block at another rate is refused (0: the "
                                          "first block's)"),
        DeclareLaunchArgument("reference_image", default_value="",
                              description="image of frame 0 as dic_tracker's DIC reference (live: else the first "
                                          "image received; from a recording: else its frame 0)"),
        DeclareLaunchArgument("time_origin_unix_ns", default_value="",
                              description="wall time (ns since the Unix epoch) of data time 0 on the stamps; live: "
                                          "the camera's frame 0 stamp minus t0_s (empty: rig.yaml's "
                                          "camera.start_time_unix_s, else now)"),
        DeclareLaunchArgument("respawn_delay", default_value="2.0", description="s before a crashed node restarts"),
        DeclareLaunchArgument("respawn_max", default_value="2",
                              description="restarts per processing node after a crash (from a recording; "
                                          "live: unlimited)"),
        DeclareLaunchArgument("foxglove", default_value="false",
                              description="true: also serve the graph to a Foxglove app (foxglove_bridge)"),
        DeclareLaunchArgument("foxglove_port", default_value="8765", description="Foxglove WebSocket server port"),
        DeclareLaunchArgument("foxglove_host", default_value="0.0.0.0",
                              description="address the Foxglove server listens on (127.0.0.1: this PC only)"),
        OpaqueFunction(function=_nodes),
    ])
