"""Topic names of the vibro graph: one definition for the nodes, launch files, recorder and docs.

Names are relative (no leading slash) so that a launch namespace or a remap moves them
(``-r __ns:=/lab1`` gives /lab1/vibro/...), except /diagnostics, which is absolute: diagnostic
aggregators and lab tools read it at the root whatever the namespace of the graph. A bag holds
the names fully qualified, as rosbag2 records them (``/vibro/frames``, or ``/lab1/vibro/frames``
under namespace ``/lab1``): see :func:`vibro_ros.bags.matching_name`.
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
    #: node names that publish it with the ``qos`` kind's profile (empty: any vibro node)
    nodes: tuple[str, ...] = ()


FRAMES = Topic("vibro/frames", "sensor_msgs/msg/Image", "stream", "frame_source",
               "camera frames, mono8/mono16, stamp = time_origin_unix_ns + t0_s + k/fps (remap to a camera "
               "driver's image_raw)",
               ("frame_source", "bag_source"))
DIC = Topic("vibro/dic", "vibro_msgs/msg/DicFrame", "history", "dic_tracker",
            "per-frame ball and structure displacement (mm, + up), valid points, ZNCC, lost flag", ("dic_tracker",))
ACCEL = Topic("vibro/accel", "vibro_msgs/msg/AccelBlock", "history", "accel_source",
              "blocks of upper/lower plate accelerations (m/s^2)", ("accel_source", "bag_source"))
ACCEL_IMPACTS = Topic("vibro/accel_impacts", "vibro_msgs/msg/AccelImpact", "results", "impact_detector",
                      "impacts detected in the accelerometers (time, plate, peak, spectrum peaks)",
                      ("impact_detector",))
STRUCTURE = Topic("vibro/structure", "vibro_msgs/msg/StructureMotion", "results", "trajectory_fitter",
                  "fitted structure sine (Eq. 2, 13)", ("trajectory_fitter",))
FLIGHTS = Topic("vibro/flights", "vibro_msgs/msg/FreeFlight", "results", "trajectory_fitter",
                "fitted free flights (Eq. 3, 14) with friction (Eq. 17)", ("trajectory_fitter",))
IMPACTS = Topic("vibro/impacts", "vibro_msgs/msg/ImpactEstimate", "results", "trajectory_fitter",
                "one estimate per impact (Eq. 15, 16), one flight after it happened", ("trajectory_fitter",))
SIMULATION = Topic("vibro/simulation", "vibro_msgs/msg/SimulationResult", "results", "simulator",
                   "simulated trajectory and deviation D (Eq. 18) per model", ("simulator",))
DISCREPANCY = Topic("vibro/discrepancy", "vibro_msgs/msg/DiscrepancyFinding", "results", "discrepancy",
                    "physics the baseline model left out, with parameters and D before/after", ("discrepancy",))
IMPACTS_FINAL_MODEL = Topic("vibro/impacts_final_model", "vibro_msgs/msg/ImpactEstimate", "results", "discrepancy",
                            "the impacts measured again under the discrepancy analysis' final model (only when a "
                            "finding changes how an impact is measured: harmonics, a flight force); final=True",
                            ("discrepancy",))
STATUS = Topic("vibro/status", "vibro_msgs/msg/StreamStatus", "results", "every node",
               "items sent/lost per stream and end-of-stream markers")
DIAGNOSTICS = Topic("/diagnostics", "diagnostic_msgs/msg/DiagnosticArray", "default", "every node",
                    "health: rate, lag, dropped/lost counts")
#: /diagnostics values of trajectory_fitter's status once its final pass ran: ``consistency``, the JSON of
#: vibro analyze's results.json 'consistency' section (vibro_fit.cross_checks.consistency_section) of the same
#: checks; ``refused``, the one-line refusal when a check refused the run (no final impact was published)
CONSISTENCY_KEY = "consistency"
REFUSED_KEY = "refused"
#: /diagnostics value of the discrepancy node's status once it ran: the JSON list of the impacts it measured with
#: a local structure velocity, where its final model's structure does not follow the measured one
#: (vibro_model.assemble.LocalStructure, as mappings); ``vibro results`` puts them in the document's impacts_model
#: section as analyze does
LOCAL_STRUCTURE_KEY = "local_structure"
#: /diagnostics value of the discrepancy node's status once it ran: the JSON of results.json's 'discrepancy'
#: section as the node computed it (baseline and final D, the findings with their extras, the engine's details),
#: which the DiscrepancyFinding messages alone do not carry; ``vibro results`` takes the section from it
DISCREPANCY_KEY = "discrepancy"
#: /diagnostics value of the discrepancy node's status once it ran: the JSON of the constant force it takes out of
#: every flight's Eq. 17 friction (an undeclared tilt, the image scale: vibro_model.assemble.FrictionCorrection as a
#: mapping; "" when none), which ``vibro results`` applies as analyze does
FRICTION_CORRECTION_KEY = "friction_correction"

ALL_TOPICS = (FRAMES, DIC, ACCEL, ACCEL_IMPACTS, STRUCTURE, FLIGHTS, IMPACTS, SIMULATION, DISCREPANCY,
              IMPACTS_FINAL_MODEL, STATUS, DIAGNOSTICS)

#: The streams a vibro/status StreamStatus names (``stream``): the data topics' last name component.
STATUS_STREAMS = ("frames", "dic", "accel", "accel_impacts", "flights", "impacts", "simulation", "discrepancy",
                  "impacts_final_model")


def status_streams(topic_names) -> set[str]:
    """The vibro/status streams of the data topics ``topic_names`` (names, relative or not): their last name
    components that are streams."""
    return {str(t).rsplit("/", 1)[-1] for t in topic_names} & set(STATUS_STREAMS)
