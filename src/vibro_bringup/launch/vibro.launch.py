"""Launch the vibro graph on a lab PC (ROS 2 Jazzy with launch_ros).

    ros2 launch vibro_bringup vibro.launch.py recording:=/data/run1 bag:=/data/bags/run1
    ros2 launch vibro_bringup vibro.launch.py recording:=/data/run1 camera_topic:=/camera/image_raw live:=true

The node list and the per-run parameters come from vibro_bringup.graph_spec, the same
definition `vibro graph` uses, so the two cannot drift apart.
"""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

from vibro_bringup.graph_spec import NODES, node_parameters


def _nodes(context, *args, **kwargs):
    recording = LaunchConfiguration("recording").perform(context)
    bag = LaunchConfiguration("bag").perform(context) or None
    live = LaunchConfiguration("live").perform(context).lower() == "true"
    camera_topic = LaunchConfiguration("camera_topic").perform(context)
    params = node_parameters(recording, bag)
    params["dic_tracker"]["live_camera"] = live
    actions = []
    for spec in NODES:
        if spec.name == "recorder" and bag is None:
            continue
        if spec.name == "frame_source" and live:
            continue  # a camera driver publishes the frames
        actions.append(Node(package=spec.package, executable=spec.executable, name=spec.name,
                            parameters=[params.get(spec.name, {})],
                            remappings=[("vibro/frames", camera_topic)], output="screen"))
    return actions


def generate_launch_description() -> LaunchDescription:
    return LaunchDescription([
        DeclareLaunchArgument("recording", description="recording directory (rig.yaml, frames/, accel.csv)"),
        DeclareLaunchArgument("bag", default_value="", description="bag directory to record to (empty: none)"),
        DeclareLaunchArgument("camera_topic", default_value="vibro/frames",
                              description="image topic to track (remap to a camera driver's image_raw)"),
        DeclareLaunchArgument("live", default_value="false", description="true: frames come from a live camera"),
        OpaqueFunction(function=_nodes),
    ])
