"""vibro_msgs definitions as they were before a change, for tests that read bags recorded then."""

from __future__ import annotations

#: vibro_msgs/DicFrame before the ball rotation (ball_rot_rad, ball_rot_std_rad): bags recorded then embed this
OLD_DICFRAME = """std_msgs/Header header
uint64 frame_index
float64 t_s
float64 ball_mm
float64 structure_mm
uint32 ball_valid_points
uint32 ball_mesh_points
uint32 structure_valid_points
uint32 structure_mesh_points
float32 ball_mean_zncc
float32 structure_mean_zncc
bool lost
string status
uint64 reference_frame_index
string run_id
"""


def old_dicframe_typestore():
    """A rosbags typestore: ROS 2 Jazzy's standard types and the old vibro_msgs/msg/DicFrame."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    store.register(get_types_from_msg(OLD_DICFRAME, "vibro_msgs/msg/DicFrame"))
    return store
