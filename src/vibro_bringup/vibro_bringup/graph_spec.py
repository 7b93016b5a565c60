"""The vibro node graph, defined once: used by ``vibro graph`` here and by the launch file on a lab PC."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml


@dataclass(frozen=True)
class NodeSpec:
    """One node: ``ros2 run <package> <executable>`` on a lab PC, ``python -m <module>`` here."""

    name: str
    package: str
    executable: str
    module: str
    role: str  # "source" (ends by itself), "processing" or "sink"


NODES: tuple[NodeSpec, ...] = (
    NodeSpec("recorder", "vibro_bringup", "recorder", "vibro_bringup.recorder_node", "sink"),
    NodeSpec("dic_tracker", "vibro_dic", "dic_tracker", "vibro_dic.dic_tracker_node", "processing"),
    NodeSpec("impact_detector", "vibro_fit", "impact_detector", "vibro_fit.impact_detector_node", "processing"),
    NodeSpec("trajectory_fitter", "vibro_fit", "trajectory_fitter", "vibro_fit.trajectory_fitter_node", "processing"),
    NodeSpec("simulator", "vibro_sim", "simulator", "vibro_sim.simulator_node", "processing"),
    NodeSpec("discrepancy", "vibro_sim", "discrepancy", "vibro_sim.discrepancy_node", "processing"),
    NodeSpec("frame_source", "vibro_dic", "frame_source", "vibro_dic.frame_source_node", "source"),
    NodeSpec("accel_source", "vibro_fit", "accel_source", "vibro_fit.accel_source_node", "source"),
)

#: Replaces frame_source and accel_source when a recorded bag is replayed (``vibro replay``).
BAG_SOURCE = NodeSpec("bag_source", "vibro_bringup", "bag_source", "vibro_bringup.bag_source_node", "source")



def default_params_file() -> Path:
    """config/vibro.yaml of the source tree, else of the installed package's share/ folder."""
    here = Path(__file__).resolve().parents[1] / "config" / "vibro.yaml"
    if here.is_file():
        return here
    from ament_index_python.packages import get_package_share_directory

    return Path(get_package_share_directory("vibro_bringup")) / "config" / "vibro.yaml"


def write_reference_frame(recording: str | Path, out_png: str | Path) -> Path | None:
    """Write frame 0 of ``recording`` (frames/ or video.avi) to ``out_png`` (lossless PNG, 8 or 16 bit).

    Returns the PNG path, or None when frame 0 cannot be read (the tracker then falls back
    to the first image it receives). The tracker uses it as its DIC reference, so a tracker
    restarted mid-run measures displacement since frame 0.
    """
    import cv2

    from vibro_io.frames import FrameSequence, find_frames_source
    from vibro_io.rig import load_rig

    rec = Path(recording)
    seq = FrameSequence(find_frames_source(rec), load_rig(rec / "rig.yaml").camera)
    first = next(iter(seq), None)
    if first is None or first.index != 0 or not first.ok:
        return None
    out_png = Path(out_png)
    if not cv2.imwrite(str(out_png), first.image):
        return None
    return out_png


def reference_from_bag(bag: str | Path, out_png: str | Path, rig_yaml: str | Path) -> Path | None:
    """Write the recorded ``vibro/frames`` image of frame 0 (index from its stamp and rig.yaml's camera)
    to ``out_png``; None when the bag holds no frame 0."""
    import cv2
    from rclpy.serialization import deserialize_message
    from sensor_msgs.msg import Image

    from vibro_dic.dic_tracker_node import image_array
    from vibro_ros import topics
    from vibro_ros.bags import read_messages
    from vibro_ros.node_support import seconds_from_stamp
    from vibro_io.rig import load_rig

    cam = load_rig(rig_yaml).camera
    for m in read_messages(bag, {topics.FRAMES.name}):
        msg = deserialize_message(m.data, Image)
        if int(round((seconds_from_stamp(msg.header) - cam.t0_s) * cam.fps)) != 0:
            continue
        out_png = Path(out_png)
        return out_png if cv2.imwrite(str(out_png), image_array(msg)) else None
    return None


def node_parameters(recording: str | Path, bag: str | Path | None, base: str | Path | None = None,
                    with_accel: bool = True, reference_image: str | Path | None = None) -> dict[str, dict[str, Any]]:
    """Parameters per node for one run: the defaults file, then the recording and bag paths, and
    ``reference_image`` (frame 0 as an image file) for dic_tracker when given."""
    data = yaml.safe_load(Path(base or default_params_file()).read_text(encoding="utf-8")) or {}
    params = {name: dict(block.get("ros__parameters", {})) for name, block in data.items()}
    rec = Path(recording).resolve()
    params.setdefault("frame_source", {})["recording"] = str(rec)
    params.setdefault("accel_source", {})["recording"] = str(rec)
    for name in ("dic_tracker", "trajectory_fitter", "simulator", "impact_detector", "discrepancy", "recorder"):
        params.setdefault(name, {})["rig_file"] = str(rec / "rig.yaml")
    params["trajectory_fitter"]["use_accelerometers"] = with_accel
    if reference_image is not None:
        params["dic_tracker"]["reference_image"] = str(Path(reference_image).resolve())
    if bag is not None:
        params.setdefault("recorder", {})["bag"] = str(Path(bag).resolve())
    return params


def write_params_file(params: dict[str, dict[str, Any]], path: str | Path) -> Path:
    """Write a ROS 2 parameters YAML (``/**/node: ros__parameters: {...}``: the node in any namespace)."""
    path = Path(path)
    path.write_text(yaml.safe_dump({(n if n.startswith("/") else f"/**/{n}"): {"ros__parameters": p}
                                    for n, p in params.items()}, sort_keys=False), encoding="utf-8")
    return path
