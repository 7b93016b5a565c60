"""vibro's Fast DDS writer defaults (``fastdds_profile.xml``): acknowledgements within 0.1 s, not 3 s.

A vibro node waits, before it exits, until its readers have acknowledged its last messages (nothing
recorded lost). With Fast DDS's default 3 s heartbeat that wait took up to 3 s per node and per step (the
final outputs, then the final diagnostics); the profile's 100 ms heartbeat ends it in about 0.1 s. Only
the timing of reliable delivery changes: QoS, transports and discovery stay as ROS sets them.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import MutableMapping

#: the profile shipped with vibro_ros
PROFILE_FILE = Path(__file__).with_name("fastdds_profile.xml")
#: where Fast DDS 2.x (Jazzy) and 3.x look for a default profiles file; a lab's own setting wins
PROFILE_VARIABLES = ("FASTRTPS_DEFAULT_PROFILES_FILE", "FASTDDS_DEFAULT_PROFILES_FILE")


def use_vibro_dds_profile(environ: MutableMapping[str, str] = os.environ) -> str | None:
    """Point Fast DDS at vibro's profile in ``environ`` (call before ``rclpy.init``). Nothing is changed when
    the RMW is not Fast DDS (``RMW_IMPLEMENTATION``) or the lab names its own profiles file. Returns the
    file set, or None."""
    rmw = environ.get("RMW_IMPLEMENTATION", "") or "rmw_fastrtps_cpp"  # Jazzy's default RMW
    if not rmw.startswith("rmw_fastrtps") or any(environ.get(v) for v in PROFILE_VARIABLES):
        return None
    environ["FASTRTPS_DEFAULT_PROFILES_FILE"] = str(PROFILE_FILE)
    return str(PROFILE_FILE)
