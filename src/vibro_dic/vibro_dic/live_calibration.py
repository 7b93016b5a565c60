"""Which lens calibration a live dic_tracker undistorts with: rig.yaml's, else the camera driver's CameraInfo.

A camera driver publishes its calibration (sensor_msgs/CameraInfo, the camera_info_manager's file) on
``camera_info`` beside its images. The tracker (:meth:`vibro_dic.tracker.DicTracker.use_calibration`) takes:

- rig.yaml's ``camera.calibration`` when it names one: the file the lab declared for the recording, which an
  offline analysis of the same images uses too. A CameraInfo that differs from it is warned about once (log and
  /diagnostics) and not used.
- else the first CameraInfo that holds a calibration (an uncalibrated driver publishes K all zero: not one),
  from its arrival on. A later, different one is warned about once and not used: a run is measured with one
  calibration. Frames tracked before it arrived were not undistorted: counted and warned about when it arrives.
- With ``camera_info_required`` (live only) and none of the two yet, an image is answered as a lost frame whose
  status says the tracker waits for the calibration; /diagnostics counts them (``frames_before_camera_info``)
  and says so (``camera_calibration``).

No rclpy here: the node hands over the message's fields.
"""

from __future__ import annotations

from typing import Any, Callable

from vibro_io.camera_calibration import CameraCalibration, CameraInfoError, calibration_from_camera_info


class LiveCalibration:
    """The calibration state of a tracker (module doc). ``topic``: the CameraInfo topic read (None: none, from a
    recording); ``warn(message)`` logs and raises /diagnostics to WARN; ``values`` is the node's /diagnostics
    key-value mapping."""

    def __init__(self, rig_calibration: CameraCalibration | None, topic: str | None, *, required: bool,
                 warn: Callable[[str], None], values: dict[str, Any]):
        self.rig_calibration = rig_calibration
        self.topic_calibration: CameraCalibration | None = None
        self.topic = topic
        self.required = required
        self._warn = warn
        self._values = values
        self._warned: set[str] = set()
        self.frames_before = 0  # frames answered lost (required) or tracked without undistortion before one came
        self._report()

    @property
    def current(self) -> CameraCalibration | None:
        """The calibration in use: rig.yaml's, else the topic's, else None."""
        return self.rig_calibration or self.topic_calibration

    @property
    def waiting(self) -> bool:
        """An image now must be answered lost: a calibration is required and none has come."""
        return self.required and self.current is None

    @property
    def waiting_status(self) -> str:
        return (f"no camera calibration yet: waiting for sensor_msgs/CameraInfo on {self.topic} "
                "(camera_info_required; rig.yaml names no camera.calibration)")

    def _warn_once(self, key: str, message: str) -> None:
        if key not in self._warned:
            self._warned.add(key)
            self._warn(message)

    def _report(self) -> None:
        if self.rig_calibration is not None:
            text = f"rig.yaml {self.rig_calibration.source}: {self.rig_calibration.describe()}"
        elif self.topic_calibration is not None:
            text = f"{self.topic}: {self.topic_calibration.describe()}"
        elif self.required:
            text = f"none yet: waiting for CameraInfo on {self.topic}"
        else:
            text = ("none: rig.yaml names no camera.calibration" + ("" if self.topic is None else
                                                                    f" and no CameraInfo came on {self.topic}")
                    + "; positions are not undistorted")
        self._values["camera_calibration"] = text
        self._values["frames_before_camera_info"] = self.frames_before

    def offer(self, width: int, height: int, k: Any, d: Any, distortion_model: str) -> None:
        """A CameraInfo message's fields (image size px, K's 9 values, D, the model)."""
        try:
            calib = calibration_from_camera_info(width, height, k, d, distortion_model, source=self.topic)
        except CameraInfoError as exc:
            self._warn_once("invalid", f"camera_info: {exc}; not used")
            return
        if calib is None:
            self._warn_once("uncalibrated", f"camera_info on {self.topic} holds no calibration (K all zero: the "
                                            "driver has none); positions are not undistorted by it")
            return
        if self.rig_calibration is not None:
            if not calib.same_as(self.rig_calibration):
                self._warn_once("differs", f"camera_info on {self.topic} ({calib.describe()}) differs from rig.yaml's "
                                           f"{self.rig_calibration.source} ({self.rig_calibration.describe()}): "
                                           "rig.yaml's is used")
            return
        if self.topic_calibration is None:
            self.topic_calibration = calib
            if self.frames_before:
                self._warn(f"camera calibration from {self.topic} from now on; the {self.frames_before} frames "
                           + ("before it were answered lost" if self.required else "tracked before it were not "
                              "undistorted"))
            self._report()
        elif not calib.same_as(self.topic_calibration):
            self._warn_once("changed", f"camera_info on {self.topic} changed mid-run ({calib.describe()}); the first "
                                       f"one ({self.topic_calibration.describe()}) stays in use for this run")

    def attach(self, tracker) -> None:
        """Give ``tracker`` the topic's calibration when it has none from rig.yaml (once); one made at another image
        size is warned about and dropped."""
        if self.rig_calibration is not None or self.topic_calibration is None:
            return
        if tracker.calibration is self.topic_calibration:
            return
        try:
            tracker.use_calibration(self.topic_calibration)
        except CameraInfoError as exc:
            self._warn(f"camera_info: {exc}; not used")
            self.topic_calibration = None
            self._report()

    def tracked_without(self) -> None:
        """An image answered before any calibration (lost when required, else not undistorted)."""
        if self.current is None:
            self.frames_before += 1
            self._values["frames_before_camera_info"] = self.frames_before
            if self.required:
                self._warn_once("waiting", self.waiting_status)
