"""Launch the vibro graph on a lab PC (ROS 2 Jazzy with launch_ros).

    ros2 launch vibro_bringup vibro.launch.py recording:=/data/run1 bag:=/data/bags/run1
    ros2 launch vibro_bringup vibro.launch.py recording:=/data/run1 bag:=""      # no recorder
    ros2 launch vibro_bringup vibro.launch.py recording:=/data/run1 camera_topic:=/camera/image_raw live:=true
    ros2 launch vibro_bringup vibro.launch.py recording:=/data/run1 bag:="" foxglove:=true   # + Foxglove server

Thin over vibro_bringup.graph_spec.launch_nodes, the node table `vibro graph` uses too (nodes,
parameters, declared readers, remappings); tests/test_launch_order.py starts what it returns
the way launch does, in shuffled order, and compares with `vibro graph`. The nodes wait for
their declared readers by name, so the start order does not matter. From a recording every
node exits once the stream has ended (launch then exits); a processing node that dies is
restarted after a delay. Live (camera-only: the recording gives the rig.yaml), processing nodes stay
up and respawn=True restarts them; the simulator and the discrepancy node are left out (they act once a
run has ended, which a live stream never does: simulate a live session once it has ended: vibro replay of
its bag).
foxglove:=true adds the Foxglove bridge (ws://<this PC>:<foxglove_port>, see docs/live.md):
from a recording it exits once the other nodes have gone; live it stays up with them.
"""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction, RegisterEventHandler, TimerAction
from launch.event_handlers import OnProcessExit
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

from vibro_bringup.graph_spec import launch_nodes


def _start(n, retries_left: int):
    """The node, and (file mode) a handler that starts it again after a non-zero exit."""
    node = Node(package=n.spec.package, executable=n.spec.executable, name=n.spec.name,
                parameters=[n.parameters], remappings=list(n.remappings), output="screen",
                respawn=n.respawn, respawn_delay=n.respawn_delay_s)
    if not n.respawn_on_failure or retries_left <= 0:
        return [node]

    def on_exit(event, context):
        if event.returncode != 0 and not context.is_shutdown:
            return [TimerAction(period=n.respawn_delay_s, actions=_start(n, retries_left - 1))]
        return None

    return [RegisterEventHandler(OnProcessExit(target_action=node, on_exit=on_exit)), node]


def _nodes(context, *args, **kwargs):
    value = lambda name: LaunchConfiguration(name).perform(context)  # noqa: E731
    actions = []
    foxglove = ({"port": int(value("foxglove_port")), "host": value("foxglove_host")}
                if value("foxglove").lower() == "true" else None)
    for n in launch_nodes(value("recording"), value("bag") or None, live=value("live").lower() == "true",
                          camera_topic=value("camera_topic"), respawn_delay_s=float(value("respawn_delay")),
                          foxglove=foxglove):
        actions += _start(n, int(value("respawn_max")))
    return actions


def generate_launch_description() -> LaunchDescription:
    return LaunchDescription([
        DeclareLaunchArgument("recording", description="recording directory (rig.yaml, frames/, accel.csv)"),
        DeclareLaunchArgument("bag", default_value="", description="bag directory to record to (empty: none)"),
        DeclareLaunchArgument("camera_topic", default_value="vibro/frames",
                              description="image topic to track (remap to a camera driver's image_raw)"),
        DeclareLaunchArgument("live", default_value="false", description="true: frames come from a live camera"),
        DeclareLaunchArgument("respawn_delay", default_value="2.0", description="s before a dead node restarts"),
        DeclareLaunchArgument("respawn_max", default_value="2",
                              description="restarts per processing node after a failure (file mode)"),
        DeclareLaunchArgument("foxglove", default_value="false",
                              description="true: also serve the graph to a Foxglove app (foxglove_bridge)"),
        DeclareLaunchArgument("foxglove_port", default_value="8765", description="Foxglove WebSocket server port"),
        DeclareLaunchArgument("foxglove_host", default_value="0.0.0.0",
                              description="address the Foxglove server listens on (127.0.0.1: this PC only)"),
        OpaqueFunction(function=_nodes),
    ])
