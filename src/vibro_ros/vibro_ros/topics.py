"""Topic names of the vibro graph: one definition for the nodes, launch files, recorder and docs.

Names are relative (no leading slash) so that a launch namespace or a remap moves them.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Topic:
    name: str
    msg_type: str  # ROS type name, package/msg/Type
    qos: str       # "stream" (reliable, flow-controlled), "results" (reliable, transient local), "history" (latched
                   # history for a restarted reader: reliable, transient local, deep), "sensor", "default"
    publisher: str
    description: str


FRAMES = Topic("vibro/frames", "sensor_msgs/msg/Image", "stream", "frame_source",
               "camera frames, mono8/mono16, stamp = t0_s + k/fps (remap to a camera driver's image_raw)")
DIC = Topic("vibro/dic", "vibro_msgs/msg/DicFrame", "history", "dic_tracker",
            "per-frame ball and structure displacement (mm, + up), valid points, ZNCC, lost flag")
ACCEL = Topic("vibro/accel", "vibro_msgs/msg/AccelBlock", "history", "accel_source",
              "blocks of upper/lower plate accelerations (m/s^2)")
ACCEL_IMPACTS = Topic("vibro/accel_impacts", "vibro_msgs/msg/AccelImpact", "results", "impact_detector",
                      "impacts detected in the accelerometers (time, plate, peak, spectrum peaks)")
STRUCTURE = Topic("vibro/structure", "vibro_msgs/msg/StructureMotion", "results", "trajectory_fitter",
                  "fitted structure sine (Eq. 2, 13)")
FLIGHTS = Topic("vibro/flights", "vibro_msgs/msg/FreeFlight", "results", "trajectory_fitter",
                "fitted free flights (Eq. 3, 14) with friction (Eq. 17)")
IMPACTS = Topic("vibro/impacts", "vibro_msgs/msg/ImpactEstimate", "results", "trajectory_fitter",
                "one estimate per impact (Eq. 15, 16), one flight after it happened")
SIMULATION = Topic("vibro/simulation", "vibro_msgs/msg/SimulationResult", "results", "simulator",
                   "simulated trajectory and deviation D (Eq. 18) per model")
DISCREPANCY = Topic("vibro/discrepancy", "vibro_msgs/msg/DiscrepancyFinding", "results", "discrepancy",
                    "physics the baseline model left out, with parameters and D before/after")
STATUS = Topic("vibro/status", "vibro_msgs/msg/StreamStatus", "results", "every node",
               "items sent/lost per stream and end-of-stream markers")
DIAGNOSTICS = Topic("diagnostics", "diagnostic_msgs/msg/DiagnosticArray", "default", "every node",
                    "health: rate, lag, dropped/lost counts")

ALL_TOPICS = (FRAMES, DIC, ACCEL, ACCEL_IMPACTS, STRUCTURE, FLIGHTS, IMPACTS, SIMULATION, DISCREPANCY,
              STATUS, DIAGNOSTICS)
