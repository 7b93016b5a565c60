"""vibro's Fast DDS defaults (``fastdds_profile.xml``): acknowledgements within 0.1 s, not 3 s, and discovery of
up to 120 participants per domain on one host, not 32.

A vibro node waits, before it exits, until its readers have acknowledged its last messages (nothing
recorded lost). With Fast DDS's default 3 s heartbeat that wait took up to 3 s per node and per step (the
final outputs, then the final diagnostics); the profile's 100 ms heartbeat ends it in about 0.1 s.

On one host (ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST) a participant announces itself to the discovery ports of the
first participant ids of its domain; past Fast DDS's default range (32 ids, measured) the participants with the
highest ids never find each other. A vibro graph run is 10 participants (nine nodes and vibro graph's monitor), so a
fourth run on one domain, or a third beside a lab's other nodes, waited 60 s and failed ("never matched"). The
profile keeps Fast DDS's built-in transports (shared memory, UDPv4) with a range of 120 ids. QoS and the
discovery range stay as ROS sets them; a lab's own profiles file (``PROFILE_VARIABLES``) replaces all of this.
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
