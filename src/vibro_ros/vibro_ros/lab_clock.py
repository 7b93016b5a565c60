"""The lab clock of vibro's header stamps: ``stamp = time origin + data time``, in integer nanoseconds.

Data time is the camera clock (frame k at ``t0_s + k / fps``; the DAQ's time column is on it up
to a small offset), in seconds from the recording's own zero. Messages keep it in their own fields
(DicFrame.t_s, AccelBlock.t_start_s, ImpactEstimate.t_s, ...). Header stamps put it on the lab's
wall clock (Unix time, UTC), so other instruments' messages and logs line up with vibro's:
``header.stamp = time_origin_unix_ns + round(data_time_s * 1e9)``. The time origin is the wall
time of data time 0: ``vibro graph`` takes it from rig.yaml's ``camera.start_time_unix_s`` (the wall
time of frame 0) or else the wall clock when the graph starts (frame 0 = now), gives it to every
node as the parameter ``time_origin_unix_ns`` and stores it in the bag's metadata (custom_data
``vibro.time_origin_unix_ns``), which ``vibro replay`` reuses. Origin 0 (a node started by hand
without it, a bag recorded before the key existed): stamps are the data time itself.

All in integer ns: a float Unix time near 1.8e9 s only resolves ~0.24 us. Imports no ROS.
"""

from __future__ import annotations

import time
from decimal import Decimal, InvalidOperation

#: The node parameter every vibro node takes (int64 ns since the Unix epoch; 0 = stamps are data time).
TIME_ORIGIN_PARAMETER = "time_origin_unix_ns"
#: The bag metadata custom_data key holding the run's origin (decimal integer ns).
BAG_TIME_ORIGIN_KEY = "vibro.time_origin_unix_ns"
NS_PER_S = 1_000_000_000


def stamp_ns_from_data_time(origin_ns: int, data_time_s: float) -> int:
    """Header stamp (ns since the Unix epoch) of data time ``data_time_s`` (s): origin + data time, rounded to 1 ns."""
    return int(origin_ns) + int(round(float(data_time_s) * 1e9))


def data_time_from_stamp_ns(origin_ns: int, stamp_ns: int) -> float:
    """Data time (s) of a header stamp ``stamp_ns`` (ns): exact inverse of :func:`stamp_ns_from_data_time`
    to within 0.5 ns (the integer difference is taken before the conversion to float)."""
    return (int(stamp_ns) - int(origin_ns)) * 1e-9


def unix_s_to_ns(unix_s: float | int) -> int:
    """A Unix time in seconds as written (e.g. in rig.yaml) to integer ns, exactly to the written digits
    (the float's shortest decimal form, not its binary value: 1718000000.123456 -> ...123456000 ns)."""
    try:
        return int((Decimal(repr(unix_s)) * NS_PER_S).to_integral_value())
    except (InvalidOperation, ValueError):
        raise ValueError(f"not a finite number of seconds: {unix_s!r}") from None


def run_time_origin_ns(t0_s: float, frame0_unix_s: float | None = None, now_ns: int | None = None) -> int:
    """The time origin of a run: the wall time (ns) of data time 0, given that frame 0 (at data time
    ``t0_s``) was at ``frame0_unix_s`` (rig.yaml's ``camera.start_time_unix_s``), or else is now."""
    frame0_ns = unix_s_to_ns(frame0_unix_s) if frame0_unix_s is not None else (
        time.time_ns() if now_ns is None else int(now_ns))
    return frame0_ns - int(round(float(t0_s) * 1e9))


def live_origin_hint(first_index: int, stamp_ns: int, t0_s: float) -> str:
    """What a live tracker says when the first camera image maps to frame ``first_index`` > 0 of the run's clock:
    the origin that would make it frame 0 (its stamp minus ``t0_s``, integer ns), to pass as the launch argument
    and parameter ``time_origin_unix_ns``. A camera that started before the graph gives a large index; the
    frames before it are not lost, they precede the session."""
    origin = int(stamp_ns) - stamp_ns_from_data_time(0, t0_s)
    return (f"the first camera image is frame {first_index} on this run's clock (time_origin_unix_ns); if it is the "
            f"camera's frame 0, start the graph with time_origin_unix_ns:={origin} (ros2 launch argument, or the "
            "nodes' parameter) so that frame numbers and times count from it")


def origin_from_custom_data(custom: dict[str, str], source: str) -> int:
    """The time origin a bag's metadata records (0 for a bag recorded before vibro stored it: its stamps
    are data time); ValueError naming ``source`` for a value that is not an integer >= 0."""
    text = custom.get(BAG_TIME_ORIGIN_KEY)
    if text is None:
        return 0
    try:
        value = int(str(text).strip())
    except ValueError:
        value = -1
    if value < 0:
        raise ValueError(f"{source}: metadata custom_data '{BAG_TIME_ORIGIN_KEY}' must be an integer >= 0 "
                         f"(ns since the Unix epoch), got {text!r}")
    return value
