"""ROS node ``dic_tracker``: sensor_msgs/Image in, one vibro_msgs/DicFrame out per frame slot.

The frame index comes from the image stamp (k = round((t - t0_s) * fps), t = stamp -
``time_origin_unix_ns``, :mod:`vibro_ros.lab_clock`), as with a live camera (whose driver stamps
with its wall clock: the origin must then be the wall time of frame 0 minus t0_s). A missing
index (a frame dropped or unreadable upstream) is answered with a lost DicFrame, so the gap is
visible downstream and the frame source's flow control keeps going.
The DIC reference (ROIs from rig.yaml) is the image file named by the parameter
``reference_image`` (``vibro graph`` sets it to frame 0 of the recording, so a tracker that
is restarted mid-run still measures displacement since frame 0), else the first image received.
vibro/dic is a latched history (``history_depth`` frames, transient local): a fitter, simulator or
discrepancy node restarted mid-run receives every DicFrame again. Frames from a second publisher,
repeated or going back, and statuses of another run stop the node (vibro_ros.guard).

Live (``live_camera``), a tracker that falls behind catches up within ``catch_up_ms`` (:mod:`vibro_dic.catch_up`):
each time it is handed an image it first takes every image waiting in its queue (only their stamps are read) into
its backlog and tracks it oldest first while its own work per frame can remove that backlog within ``catch_up_ms``;
beyond that it tracks every 2nd, 3rd, ... image (the stride :func:`vibro_dic.catch_up.stride_for` gives) and passes
over the others (tracking resumes from the motion prediction across the gap), so the losses are spread and the
lag is worked off in ``catch_up_ms``. Images passed over are answered with lost DicFrames whose status is
:data:`vibro_dic.catch_up.SKIPPED`; /diagnostics counts them (``skipped_count``, ``catch_up_episodes``,
``catch_up_largest``, ``catch_up_last``) and gives the latest stride (``catch_up_stride``, 1 = every image)
and the tracker's own work per frame (``work_ms_per_frame``).

Images are taken serialized (a raw subscription) and read in place (:mod:`vibro_dic.raw_image`: the stamp, size,
encoding and step from the CDR bytes, the pixels a view into them, converted into one float32 buffer for the DIC);
an image that cannot be read (cut short, another encoding, a step or size that does not fit) is answered with a
lost DicFrame whose status names the field. DicFrames are written as CDR bytes (:mod:`vibro_dic.dic_frame_cdr`) and
published raw once the readers have matched; the bytes are checked against rclpy's serialization at start, and the
node publishes messages instead if they differ.
"""

from __future__ import annotations

import math
import sys
import time

import numpy as np
from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.node import Node
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import CameraInfo, Image

from vibro_io.camera_calibration import calibration_of_rig
from vibro_io.dictrack import FrameTrack
from vibro_io.frames import read_image
from vibro_io.rig import check_rois_in_image, load_rig
from vibro_model.errors import RecordingError
from vibro_msgs.msg import DicFrame, StreamStatus
from vibro_ros import topics
from vibro_ros.adaptive_qos import results_subscription
from vibro_ros.convert import frame_track_to_message
from vibro_ros.guard import InputGuard
from vibro_ros.lab_clock import live_origin_hint
from vibro_ros.node_support import (
    STREAM_QOS,
    Health,
    StatusPublisher,
    declare,
    history_depth_parameter,
    history_qos,
    run_node,
    sensor_qos,
    time_origin_parameter,
)
from vibro_ros.readiness import ReaderGate

from .ball_method import resolve_ball_method
from .catch_up import DEFAULT_CATCH_UP_MS, SKIPPED, CatchUpPolicy, CatchUpStats
from .dic_frame_cdr import DicFrameEncoder
from .live_calibration import LiveCalibration
from .quality import TrackQuality
from .raw_image import ImageDecodeError, RawImage, cdr_stamp_ns, decode_image
from .texture import DEFAULT_MAX_SUBSET_SIGMA_PX, check_texture
from .tracker import METHODS, DicTracker, compile_kernels

#: Longest run (s of camera time) a frame stamp may lie after the time origin.
MAX_RUN_S = 86400.0
#: (s) the longest a live tracker works through its backlog in one callback before its timers get a turn
WORK_SLICE_S = 0.02
#: the status (and log line) of a frame slot whose image was received but could not be read (its reason after it)
UNREADABLE = "image unreadable"
_DTYPES = {"mono8": np.uint8, "8UC1": np.uint8, "mono16": np.uint16, "16UC1": np.uint16}


def image_array(msg: Image) -> np.ndarray:
    """The pixels of a mono8/mono16 Image as a 2-D array; RecordingError for other encodings."""
    dtype = _DTYPES.get(msg.encoding)
    if dtype is None:
        raise RecordingError(f"image encoding {msg.encoding!r} not supported (mono8 or mono16)")
    itemsize = np.dtype(dtype).itemsize
    if msg.step < msg.width * itemsize or len(msg.data) < msg.step * msg.height:
        raise RecordingError(f"image {msg.width}x{msg.height} step {msg.step}: data has {len(msg.data)} bytes")
    buf = np.frombuffer(msg.data, dtype=np.uint8).reshape(msg.height, msg.step)[:, : msg.width * itemsize]
    img = np.ascontiguousarray(buf).view(dtype)
    if msg.is_bigendian and itemsize > 1:
        img = img.byteswap()
    return img


def dic_message(row: FrameTrack, mesh_points: tuple[int, int], status: str = "", reference_frame_index: int = 0,
                run_id: str = "", origin_ns: int = 0) -> DicFrame:
    """The DicFrame of ``row`` (displacements mm, ball rotation rad and its sigma): ``t_s`` camera time, the header
    stamped with it on the lab clock of ``origin_ns`` (:func:`vibro_ros.convert.frame_track_to_message`)."""
    return frame_track_to_message(row, mesh_points, status, reference_frame_index, run_id, origin_ns)


#: live: images the best-effort image reader keeps (parameter ``image_queue_depth``). The sensor QoS's 5 lost 4-40
#: images in a run whenever the tracker waited ~5 ms for a core (bench_live.py, 1000 Hz, 2 cores); 50 lost none.
DEFAULT_IMAGE_QUEUE_DEPTH = 50

#: live, the first image may come this long (s of camera time) after the reference frame: the slots between are
#: answered as lost (the session's first images dropped); later, the clock's origin is wrong (the tracker says
#: which origin makes its first image frame 0) or the tracker was restarted mid-run
LEADING_SLOTS_S = 0.5



class DicTrackerNode(Node):
    def __init__(self) -> None:
        super().__init__("dic_tracker")
        rig_file = declare(self, "rig_file", "", "rig.yaml giving fps, t0_s, mm_per_px, subset size and ROIs")
        self.method = declare(self, "method", "icgn", f"sub-pixel method: {' or '.join(METHODS)}")
        self.zncc_min = float(declare(self, "zncc_min", 0.6, "a mesh point below this ZNCC is rejected"))
        live = bool(declare(self, "live_camera", False,
                            "true: best-effort sensor QoS for a camera driver's image_raw"))
        self.live_camera = live
        catch_up_ms = float(declare(
            self, "catch_up_ms", DEFAULT_CATCH_UP_MS, "live: the time (ms) within which a tracker that fell behind "
            "works off its backlog: every image, oldest first, while its work per frame allows that; else every "
            "2nd, 3rd, ... image, the others skipped (reported lost, spread). 0 = always the newest image"))
        image_queue_depth = int(declare(
            self, "image_queue_depth", DEFAULT_IMAGE_QUEUE_DEPTH, "live: images the best-effort reader keeps while the "
            "tracker is busy or waits for a core (sensor QoS, keep last): a deeper queue loses none in a short stall"))
        if image_queue_depth < 1:
            raise RecordingError(f"dic_tracker: parameter 'image_queue_depth' must be >= 1, got {image_queue_depth}")
        self.end_wait_s = float(declare(
            self, "end_wait_s", 5.0, "once the frame source has ended, finish after this long without an image (s): "
            "a tracker restarted after the last frame gets none; the slots it never answered count as lost downstream"))
        reference = declare(self, "reference_image", "",
                            "image file (PNG/TIFF) of frame 0, the DIC reference; empty = the first image received")
        self.frames_expected = int(declare(
            self, "frames_expected", 0, "frames the run will bring (vibro graph sets it from the recording; 0 = "
            "unknown until the frame source ends): diagnostics report frames_done / frames_expected as progress"))
        self.max_subset_sigma_px = float(declare(
            self, "max_subset_sigma_px", DEFAULT_MAX_SUBSET_SIGMA_PX,
            "texture check: a subset whose predicted displacement sigma (px) exceeds this is not used"))
        if not rig_file:
            raise RecordingError("dic_tracker: parameter 'rig_file' is required")
        if self.frames_expected < 0:
            raise RecordingError(f"dic_tracker: parameter 'frames_expected' must be >= 0, got {self.frames_expected}")
        if not (math.isfinite(self.max_subset_sigma_px) and self.max_subset_sigma_px > 0):
            raise RecordingError(f"dic_tracker: parameter 'max_subset_sigma_px' must be a positive number of px, "
                                 f"got {self.max_subset_sigma_px}")
        if self.method not in METHODS:
            raise RecordingError(f"dic_tracker: parameter 'method' must be one of {METHODS}, got {self.method!r}")
        self.rig = load_rig(rig_file)
        # the DIC kernels loaded from numba's cache (compiled on a machine's first run) before any image can
        # arrive: their first call, ~0.3 s (~5 s uncached), must not fall on the first frame
        self.get_logger().debug(f"DIC kernels ready in {compile_kernels():.2f} s")
        try:
            self.catch_up_policy = CatchUpPolicy(1.0 / self.rig.camera.fps, 1e-3 * catch_up_ms)
        except ValueError as exc:
            raise RecordingError(f"dic_tracker: parameter 'catch_up_ms': {exc}") from None
        self.time_origin_ns = time_origin_parameter(self)
        self.reference_file = str(reference)
        self.reference: np.ndarray | None = None
        if self.reference_file:
            try:
                self.reference = read_image(self.reference_file)
                check_rois_in_image(self.rig, *self.reference.shape)
            except RecordingError as exc:
                raise RecordingError(f"dic_tracker: parameter 'reference_image': {exc}") from None
        self.tracker: DicTracker | None = None
        self._started = False  # the first image has been received (and the tracker checked against it)
        self.quality: TrackQuality | None = None
        self.next_index = 0
        self.reference_index: int | None = 0 if self.reference is not None else None  # the stream begins here
        self.published = self.lost = self.received = 0
        self._last_image_at = time.monotonic()  # since start: a tracker restarted after the end gets no image
        self._warned_idle = False
        self.frames_finished: StreamStatus | None = None
        self.health = Health(self)
        self.health.rate_counter = "tracked"
        self.status = StatusPublisher(self, "dic")
        self.guard = InputGuard(self)
        self.guard.watch(topics.FRAMES)
        self.pub = self.create_publisher(DicFrame, topics.DIC.name, history_qos(history_depth_parameter(self)))
        # DicFrames written as CDR bytes and published raw (vibro_dic.dic_frame_cdr), if they read back as rclpy's
        self._encoders: dict[tuple[int, int], DicFrameEncoder] = {}
        self._raw_dic = DicFrameEncoder((0, 0), self.time_origin_ns).matches(
            serialize_message, lambda b: deserialize_message(b, DicFrame),
            lambda row, status, ref, run_id: dic_message(row, (0, 0), status, ref, run_id, self.time_origin_ns))
        if not self._raw_dic:
            self.get_logger().warning("DicFrame CDR bytes written here differ from rclpy's (DicFrame.msg changed?): "
                                      "publishing messages (more CPU per frame)")
        results_subscription(self, StreamStatus, topics.STATUS.name, self._on_status)
        self.catch_up = CatchUpStats()
        self._skipped: set[int] = set()  # frame indices received and passed over for a newer image (live)
        self._backlog: list[tuple[int, bytes]] = []  # live: serialized images taken, not yet tracked (oldest first)
        self._pixels: np.ndarray | None = None  # the float32 buffer every image is converted into for the DIC
        # serialized images (raw): read in place (vibro_dic.raw_image), never deserialized into messages
        self._image_sub = self.create_subscription(
            Image, topics.FRAMES.name, self._on_image, sensor_qos(image_queue_depth) if live else STREAM_QOS,
            event_callbacks=SubscriptionEventCallbacks(matched=self._on_image_publishers), raw=True)
        self.create_timer(1.0, self._report)
        self.calibration = self._lens_calibration(live)
        self._resume_timer = None
        if live:  # a backlog left when a work slice ended and no image came after it (the end of the stream): run
            # only while one is left (a timer firing every 5 ms cost the idle tracker ~0.02 ms of CPU per frame)
            self._resume_timer = self.create_timer(WORK_SLICE_S / 4, self._resume_backlog)
            self._resume_timer.cancel()
        self._held: list[DicFrame] = []  # results kept back until every declared reader of vibro/dic matched
        # readers (the fitter, simulator, discrepancy, recorder, the frame source's acknowledgements) by name;
        # the node exits once they have acknowledged everything (file mode)
        self.gate = ReaderGate(self, on_open=self._release, health=self.health)
        self.done = self.gate.done
        if live:
            self._prepare_live()

    def _prepare_live(self) -> None:
        """Live with a reference file: build the DIC tracker (meshes, templates, the texture check on the
        reference alone: an upper bound on the noise) now, not on the first image, whose ~15 ms of set-up would
        drop the camera's next images from a shallow sensor queue; run every per-image code path once on the
        reference (:meth:`_warm_up`); then, once the declared readers of vibro/dic have matched, report ``ready``
        on /diagnostics and in the log (a lab triggers its camera once the graph says so). Without a reference
        file the first image is the reference and ``ready`` says so."""
        self._ready_announced = False
        if self.reference is None:
            self.health.values["ready"] = "false: no reference_image, the first image received becomes it"
            return
        self._build_tracker(self.reference, self.reference)
        self._warm_ms = self._warm_up()
        self.health.values["ready"] = "false: tracker built and warm, waiting for the readers of vibro/dic"
        if self.gate.open:
            self._announce_ready()

    def _warm_up(self) -> float:
        """Every per-image path once, on the reference as frames 0-3 (so the prediction path runs too): the image
        serialized and read in place as a camera's are (its stamp, its pixels into the float32 buffer), DIC, the
        DicFrame's bytes; then the motion history is forgotten. The first call of each costs a multiple of the next
        (imports, caches, allocations) and must not fall on the camera's first images. Returns its ms."""
        t0 = time.perf_counter()
        ref = self.reference
        enc = "mono8" if ref.dtype == np.uint8 else "mono16"
        msg = Image(height=ref.shape[0], width=ref.shape[1], encoding=enc, step=ref.shape[1] * ref.itemsize,
                    data=ref.tobytes())
        raw = serialize_message(msg)
        cdr_stamp_ns(raw)
        image = self._float_pixels(decode_image(raw))
        cam = self.rig.camera
        mesh = self._mesh_points()
        for k in range(4):
            row = self.tracker.track_image(k, cam.frame_time_s(k), image)
            dic_message(row, mesh, "", 0, self.guard.run_id, self.time_origin_ns)
            self._encoder(mesh).encode(row, "", 0, self.guard.run_id)
        for mesh in (self.tracker.ball, self.tracker.structure):
            mesh.reseed()
            for counter in ("n_widened", "n_global", "n_predicted"):
                if hasattr(mesh, counter):
                    setattr(mesh, counter, 0)
        self.tracker._segment = None
        return 1e3 * (time.perf_counter() - t0)

    def _announce_ready(self) -> None:
        if self._ready_announced:
            return
        self._ready_announced = True
        self.health.values["ready"] = "true"
        self.health.publish()
        self.get_logger().info(f"ready: reference {self.reference_file} loaded, the tracker built and warm "
                               f"({self._warm_ms:.0f} ms), the readers of vibro/dic matched; start the camera")

    @property
    def _released(self) -> bool:
        return self.gate.open

    def _release(self) -> None:
        """Every declared reader matched vibro/dic: send what was held, in order."""
        for msg in self._held:
            self.pub.publish(msg)
        self._held.clear()
        if self.live_camera and self.reference is not None and self.tracker is not None:
            self._announce_ready()
        self._maybe_finish()

    def _index_of_ns(self, stamp: int) -> int:
        cam = self.rig.camera
        return int(round(((stamp - self.time_origin_ns) / 1e9 - cam.t0_s) * cam.fps))

    def _on_image(self, msg: bytes | Image) -> None:
        """An image from the frame topic, serialized (the subscription is raw; an Image message, as a test may
        hand over, is serialized first); live, it joins the backlog with every image already waiting behind it,
        which is tracked oldest first within ``catch_up_ms`` (:mod:`vibro_dic.catch_up`)."""
        raw = msg if isinstance(msg, bytes) else serialize_message(msg)
        if not self.live_camera:
            self._take(raw)
            return
        self._queue(raw)
        self._work_backlog()

    def _queue(self, raw: bytes) -> None:
        """A serialized image into the backlog by its stamp's frame index; one whose stamp cannot be read is
        reported (it has no frame slot: its slot is answered lost as not received, once a later image comes)."""
        try:
            self._backlog.append((self._index_of_ns(cdr_stamp_ns(raw)), raw))
        except ValueError as exc:
            self._unreadable_stamp(exc)

    def _unreadable_stamp(self, exc: Exception) -> None:
        message = f"{UNREADABLE}: {exc}; its frame slot is answered lost once a later image comes"
        self.health.count("unreadable")
        self.health.warn(message)
        self.get_logger().error(message)

    def _lens_calibration(self, live: bool) -> LiveCalibration:
        """The lens calibration: rig.yaml's, else (live) the camera driver's CameraInfo (vibro_dic.live_calibration),
        subscribed to beside the image topic unless ``camera_info_topic`` names one."""
        topic = str(declare(
            self, "camera_info_topic", "", "live: the sensor_msgs/CameraInfo topic of the camera's calibration, used "
            "when rig.yaml names no camera.calibration (latched or sensor QoS); empty = camera_info beside the image "
            "topic (/camera/image_raw -> /camera/camera_info)"))
        required = bool(declare(
            self, "camera_info_required", False, "live: answer images as lost until a calibration is known (rig.yaml "
            "camera.calibration or a CameraInfo); false: track them without undistortion"))
        if not topic:
            topic = self._image_sub.topic_name.rsplit("/", 1)[0] + "/camera_info"
        calibration = LiveCalibration(calibration_of_rig(self.rig), topic if live else None,
                                      required=live and required, warn=self._warn, values=self.health.values)
        if live:  # keyword arguments: --help lists the topic under the parameter camera_info_topic
            results_subscription(node=self, msg_type=CameraInfo, topic=topic, callback=self._on_camera_info,
                                 profile=history_qos(1))
        return calibration

    def _warn(self, message: str) -> None:
        self.get_logger().warning(message)
        self.health.warn(message)

    def _on_camera_info(self, msg: CameraInfo) -> None:
        """The camera driver's calibration (:mod:`vibro_dic.live_calibration`), given to the tracker once built."""
        self.calibration.offer(msg.width, msg.height, msg.k, msg.d, msg.distortion_model)
        if self.tracker is not None:
            self.calibration.attach(self.tracker)

    def _on_image_publishers(self, info) -> None:
        """A camera (image publisher) matched or left this reader: logged and on /diagnostics
        (``image_publishers_matched``). Images sent before the match never arrive: a lab triggers its camera once
        the tracker says ready and this line shows its driver matched."""
        self.health.values["image_publishers_matched"] = int(info.current_count)
        if info.current_count_change > 0:
            self.get_logger().info(f"image publisher matched on {self._image_sub.topic_name} "
                                   f"({info.current_count} now)")
        elif info.current_count_change < 0:
            self.get_logger().warning(f"image publisher left {self._image_sub.topic_name} "
                                      f"({info.current_count} now)")

    def _resume_backlog(self) -> None:
        if self._backlog:
            self._work_backlog()
        if not self._backlog:
            self._resume_timer.cancel()

    def _take_waiting(self) -> None:
        """The images queued in the subscription meanwhile, serialized, into the backlog: only their stamps are
        read."""
        take = self._image_sub.handle.take_message
        while True:
            got = take(Image, True)
            if got is None:
                return
            self._queue(got[0])

    def _work_backlog(self) -> None:
        """Track the backlog, oldest first or thinned (:class:`vibro_dic.catch_up.CatchUpPolicy`; the images passed
        over reported lost as skipped),
        for at most :data:`WORK_SLICE_S` per call so that the node's timers and status still run; the next image
        or the resume timer goes on."""
        started = time.monotonic()
        while True:
            self._take_waiting()
            if not self._backlog:
                return
            choice = self.catch_up_policy.choose([k for k, _ in self._backlog], time.monotonic())
            n_skip = len(choice.skipped)
            if n_skip:
                for k in choice.skipped:  # in arrival order: a stamp repeated or going back stops the node as before
                    if k < 0 or not self.guard.accept(topics.FRAMES.name, index=k, what="frame"):
                        if k < 0:  # a stamp before the origin: let the tracked image's checks name it
                            continue
                        self._backlog.clear()
                        return
                self._skipped.update(k for k in choice.skipped if k >= 0)
                self.received += n_skip
                self.catch_up.add(choice)
                self.health.count("skipped", n_skip)
                self.health.values["catch_up_episodes"] = self.catch_up.episodes
                self.health.values["catch_up_largest"] = self.catch_up.largest
                self.health.values["catch_up_last"] = f"frames {self.catch_up.last[0]}..{self.catch_up.last[1]}"
            raw = self._backlog[n_skip][1]
            del self._backlog[:n_skip + 1]
            work_started = time.thread_time()  # this thread's CPU: a frame's own work, not the time others took
            self._take(raw)
            self.catch_up_policy.worked(time.thread_time() - work_started)
            if time.monotonic() - started > WORK_SLICE_S:
                if self._backlog and self._resume_timer is not None:
                    self._resume_timer.reset()  # the rest after the timers' turn, even if no image comes
                return

    def _plausible(self, k: int, stamp: int) -> bool:
        """False (and the node stops, exit code 2) for a frame whose stamp (ns) is not within a day after the
        time origin: a camera driver stamping with its wall clock while ``time_origin_unix_ns`` is not
        the wall time of its frame 0 (the index would be negative or count billions of missing frames)."""
        t_s = (stamp - self.time_origin_ns) * 1e-9  # vibro_ros.lab_clock.data_time_from_stamp_ns
        if k >= 0 and t_s - self.rig.camera.t0_s <= MAX_RUN_S:
            return True
        if not self.guard.check_publishers():  # a foreign camera explains the stamp: it is named instead
            return False
        sec, nanosec = divmod(stamp, 1_000_000_000)
        self.guard.fail(f"{topics.FRAMES.name}: image stamp {sec}.{nanosec:09d} s "
                        f"is {t_s:.3f} s from time_origin_unix_ns={self.time_origin_ns} (frame index {k}): set "
                        "time_origin_unix_ns to the wall time (ns) of the camera's frame 0 minus rig.yaml t0_s",
                        topics.FRAMES.name)
        return False

    def _mesh_points(self) -> tuple[int, int]:
        return (len(self.tracker.ball.points), len(self.tracker.structure.points)) if self.tracker else (0, 0)

    def _encoder(self, mesh: tuple[int, int]) -> DicFrameEncoder:
        enc = self._encoders.get(mesh)
        if enc is None:
            enc = self._encoders[mesh] = DicFrameEncoder(mesh, self.time_origin_ns)
        return enc

    def _publish(self, row: FrameTrack, status: str = "") -> None:
        mesh = self._mesh_points()
        if self.reference_index is None:  # no reference file: the stream begins at the first frame answered
            self.reference_index = row.frame
        if self._released:
            if self._raw_dic:  # the CDR bytes, written here: no message object, no conversion in rclpy
                self.pub.publish(self._encoder(mesh).encode(row, status, self.reference_index, self.guard.run_id))
            else:
                self.pub.publish(dic_message(row, mesh, status, self.reference_index, self.guard.run_id,
                                             self.time_origin_ns))
        else:
            self._held.append(dic_message(row, mesh, status, self.reference_index, self.guard.run_id,
                                          self.time_origin_ns))
            self.gate.start_clock()
        self.published += 1
        if row.lost:
            self.lost += 1
            self.health.count("lost")
        self.health.count("tracked")

    def _take(self, raw: bytes) -> None:
        """One serialized image: its frame slot from the stamp, the slots before it answered (lost: never received
        or passed over), then tracked, or answered lost with the reason it cannot be (unreadable, no calibration
        yet)."""
        try:
            stamp = cdr_stamp_ns(raw)
        except ValueError as exc:
            self._unreadable_stamp(exc)
            return
        k = self._index_of_ns(stamp)
        if not self._plausible(k, stamp):
            return
        if not self.guard.accept(topics.FRAMES.name, index=k, what="frame"):
            return
        self.received += 1
        self._last_image_at = time.monotonic()
        t = self.rig.camera.frame_time_s(k)
        try:
            image = decode_image(raw)
            if not self._started:
                if k > self.rig.camera.fps * LEADING_SLOTS_S and self.live_camera:
                    hint = live_origin_hint(k, stamp, self.rig.camera.t0_s)
                    self.get_logger().warning(hint)
                    self.health.warn(hint)
                self._start_tracker(k, image.native())
            pixels = self._float_pixels(image)
            error = ""
        except RecordingError as exc:
            if not self._started:  # no tracker yet: the stream begins at a later image
                self._refuse(k, t, exc)
                return
            error = str(exc)
        why = ("no image received (dropped or unreadable upstream)" if self.received > 1 else
               "before the first image received (the camera started before the tracker, or its first images "
               "were dropped)")
        for gap in range(self.next_index, k):  # frames that never arrived, or were passed over (live)
            gt = self.rig.camera.frame_time_s(gap)
            self._publish(FrameTrack(frame=gap, t_s=gt, ball_mm=math.nan, structure_mm=math.nan, ball_valid=0,
                                     structure_valid=0, ball_zncc=math.nan, structure_zncc=math.nan, lost=True),
                          SKIPPED if gap in self._skipped else why)
        self._skipped.clear()
        if error:
            self._refuse(k, t, error)
            return
        if self.live_camera:
            self.calibration.tracked_without()
        if self.calibration.waiting:
            self._publish(FrameTrack(frame=k, t_s=t, ball_mm=math.nan, structure_mm=math.nan, ball_valid=0,
                                     structure_valid=0, ball_zncc=math.nan, structure_zncc=math.nan, lost=True),
                          self.calibration.waiting_status)
            self.next_index = k + 1
            return
        row = self.tracker.track_image(k, t, pixels)
        self.quality.add(k, self.tracker.last_results)
        reasons = "; ".join(r.reason for r in self.tracker.last_results.values() if r.lost and r.reason)
        self._publish(row, reasons)
        self.health.observe(t)
        self.next_index = k + 1
        self._maybe_finish()

    def _refuse(self, k: int, t: float, exc: Exception | str) -> None:
        """Frame ``k``'s image received but not usable: a lost DicFrame with the reason, logged and on
        /diagnostics."""
        self.health.error(str(exc))
        self.get_logger().error(f"frame {k}: {exc}")
        self._publish(FrameTrack(frame=k, t_s=t, ball_mm=math.nan, structure_mm=math.nan, ball_valid=0,
                                 structure_valid=0, ball_zncc=math.nan, structure_zncc=math.nan, lost=True), str(exc))
        self.next_index = k + 1

    def _float_pixels(self, image: RawImage) -> np.ndarray:
        """The pixels of ``image`` in the tracker's float32 buffer (one for the run: the DIC reads the image only
        while tracking it); ImageDecodeError when its size or pixel type is not the reference's."""
        buf = self._pixels
        if (image.height, image.width) != buf.shape:
            raise ImageDecodeError(f"image height/width: {image.width}x{image.height} differs from the "
                                   f"reference's {buf.shape[1]}x{buf.shape[0]}")
        if image.dtype.itemsize != self._pixel_bytes:
            raise ImageDecodeError(f"image encoding {image.encoding!r}: {8 * image.dtype.itemsize}-bit pixels, the "
                                   f"reference's are {8 * self._pixel_bytes}-bit")
        np.copyto(buf, image.pixels())
        return buf

    def _start_tracker(self, k: int, image: np.ndarray) -> None:
        """Build the DicTracker on the reference file (checked against this first image) or on ``image``
        (a tracker built ahead, live, is only checked)."""
        image = np.array(image)  # its own copy: the view into the message's bytes is read-only and short-lived
        if self.reference is not None:
            ref = self.reference
            if ref.shape != image.shape or ref.dtype != image.dtype:
                raise RecordingError(
                    f"reference_image {self.reference_file}: {ref.shape[1]}x{ref.shape[0]} {ref.dtype} does not "
                    f"match the incoming images ({image.shape[1]}x{image.shape[0]} {image.dtype})")
            if k != 0:
                self.get_logger().warning(f"first image received is frame {k}; displacements are measured "
                                          f"against frame 0 from {self.reference_file}")
        else:
            check_rois_in_image(self.rig, *image.shape)
            ref = image
            if k != 0:
                self.get_logger().warning(f"first image is frame {k}; it is the DIC reference")
        if self.tracker is None:
            self._build_tracker(ref, image)
        self.next_index = k
        leading = k - (self.reference_index or 0)
        if self.live_camera and self.reference is not None and 0 < leading <= self.rig.camera.fps * LEADING_SLOTS_S:
            # a live session's first images dropped (or the camera started a moment early): the stream still
            # begins at the reference frame, its first slots answered as lost, so readers take the run whole
            self.next_index = self.reference_index or 0
        self._started = True

    def _build_tracker(self, ref: np.ndarray, image: np.ndarray) -> None:
        """The DicTracker on reference ``ref`` with its texture check (noise from ``image`` against ``ref``)."""
        # the ball's method: rig.yaml's, else chosen by the reference's texture as every tracking path does
        choice = resolve_ball_method(ref, self.rig.dic)
        if choice.source != "rig.yaml":
            self.get_logger().info(f"ball: {choice.describe()}")
            if choice.method == "outline":
                self.health.warn(f"ball: {choice.describe()}")
        tracker = DicTracker.for_rig(ref, self.rig, method=self.method, zncc_min=self.zncc_min)
        # the texture check (vibro_dic.texture): noise from this image against the reference when they differ,
        # else from the reference alone (an upper bound on speckle); a refusal is raised like a bad ROI
        texture, warnings = check_texture(ref, image, choice.dic, max_subset_sigma_px=self.max_subset_sigma_px)
        for w in warnings:
            self.get_logger().warning(f"texture: {w}")
            self.health.warn(f"texture: {w}")
        tracker.use_texture(texture)
        self.calibration.attach(tracker)  # the camera driver's, when rig.yaml names none
        self._pixels = np.empty(ref.shape, dtype=np.float32)
        self._pixel_bytes = ref.dtype.itemsize
        self.quality = TrackQuality(texture)
        self.quality.ball_method = choice
        self.tracker = tracker

    def _on_status(self, msg: StreamStatus) -> None:
        if not self.guard.accept(topics.STATUS.name, run_id=msg.run_id):
            return
        if msg.stream == "frames" and msg.finished:
            self.frames_finished = msg
            self._maybe_finish()

    @property
    def finished(self) -> bool:
        """Every image the frame source announced has been tracked, or none has come for ``end_wait_s`` since
        the source ended (a tracker restarted after the last frame)."""
        src = self.frames_finished
        # every image announced arrived, or every frame slot up to the last has been answered
        return src is not None and (self.received >= src.items_sent
                                    or self.next_index >= src.items_sent + src.items_lost
                                    or self._idle_after_end)

    @property
    def _idle_after_end(self) -> bool:
        if self.frames_finished is None or time.monotonic() - self._last_image_at < self.end_wait_s:
            return False
        if not self._warned_idle:
            self._warned_idle = True
            src = self.frames_finished
            msg = (f"the frame source has ended ({src.items_sent} images sent) and none came for "
                   f"{self.end_wait_s:g} s: finishing after {self.received} images from frame {self.next_index}; "
                   "slots this tracker never answered count as lost downstream")
            self.get_logger().warning(msg)
            self.health.warn(msg)
        return True

    def _maybe_finish(self) -> None:
        if self.finished and self._released:
            self._progress()  # the diagnostics published when the node stops hold the final count
            self.status.publish(self.published, self.lost, True)
            self.gate.finish()

    def _progress(self) -> None:
        """frames_done (slots answered) / frames_expected (the parameter, else the frame source's count once it
        has ended; 0 = unknown) and their ratio as ``progress`` (empty while unknown); each body's median ZNCC."""
        expected = self.frames_expected
        src = self.frames_finished
        if not expected and src is not None:
            expected = int(src.items_sent + src.items_lost)
        self.health.values["frames_done"] = self.published
        self.health.values["frames_expected"] = expected
        self.health.values["progress"] = f"{min(self.published / expected, 1.0):.3f}" if expected else ""
        if self.quality is not None:
            for name, b in self.quality.summary()["bodies"].items():
                med = b["zncc_median"]
                self.health.values[f"{name}_zncc_median"] = "" if med is None else f"{med:.4f}"
                self.health.values[f"{name}_frames_below_zncc_warn"] = b["frames_below_zncc_warn"]

    def _report(self) -> None:
        self._maybe_finish()
        self._progress()
        if self.live_camera:  # the catch-up's state, once a second (not per frame: that cost CPU per frame)
            self.health.values["catch_up_stride"] = self.catch_up_policy.stride
            work_s = self.catch_up_policy.cost_s
            if work_s is not None:  # None while every image tracked came after a gap (catch_up_ms 0)
                self.health.values["work_ms_per_frame"] = round(1e3 * work_s, 3)
        self.health.values["frames_lost"] = self.lost
        self.status.publish(self.published, self.lost, self.finished and self._released)


def main(args: list[str] | None = None) -> int:
    return run_node(DicTrackerNode, args)


if __name__ == "__main__":
    sys.exit(main())
