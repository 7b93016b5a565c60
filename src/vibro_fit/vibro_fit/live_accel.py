"""A live accelerometer stream (a DAQ driver's AccelBlocks on ``vibro/accel``): what a driver must send, the checks
of every block, and the camera-to-DAQ clock offset from the blocks' lab-clock stamps, refined from the impacts.

No rclpy here: ``impact_detector`` and ``trajectory_fitter`` call it from their block callbacks with the
message's fields. The contract (docs/live.md, *Live accelerometers*):

- ``sample_rate_hz`` the same on every block, at least :data:`MIN_RATE_HZ`, and the node's ``accel_rate_hz``
  parameter when it is set (a wrong rate is refused: every time and every impact would be wrong by its ratio);
- a fixed number of samples per block, ``upper_ms2`` and ``lower_ms2`` of equal length, in m/s^2 (+ up);
- ``block_index`` + 1 per block (from any start: the first block received begins the stream); a missing index is
  a lost block; ``first_sample_index`` the DAQ's sample count, ``t_start_s`` its time of that sample
  (``t_start_s`` advancing by exactly the previous block's duration: a jump without a missing block is samples
  lost inside the driver);
- ``header.stamp`` the lab-clock time (the clock the camera stamps with) at which the block's first sample was
  taken, never going back. Then t_daq - t_camera = ``t_start_s`` - (stamp - ``time_origin_unix_ns``).

A refusal ends the node (exit code 2, one line); lost blocks and samples, late stamps and clipping are counted and
reported, and the impact detection restarts after a discontinuity (its high-pass must not run across one).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .accel_impacts import ClockOffset, refine_clock_offset

#: lowest sample rate taken: an impact's ringing (kHz) must be sampled, and its onset timed to ~0.1 ms
MIN_RATE_HZ = 10_000.0
#: a block's t_start_s may differ from the end of the block before by this fraction of a sample
CONTINUITY_SAMPLES = 0.5
#: blocks whose stamp offsets give the stamp-based clock offset (their median)
STAMP_WINDOW = 256
#: (Hz) the rate a live node warms its detection for when accel_rate_hz is not given (the recommended DAQ rate)
LIVE_RATE_GUESS_HZ = 50_000.0


class AccelStreamRefused(ValueError):
    """A block no live accelerometer stream may carry (wrong or changing rate, unequal channels, stamps going
    back): the node stops with this message."""


@dataclass
class BlockVerdict:
    """What one accepted block means: ``lost_blocks`` / ``lost_samples`` before it (0 when it continues the
    stream), ``restart`` when the detection must not bridge to it, ``warnings`` (one line each) to report,
    ``clipped_samples`` per channel at or beyond the stated full scale, ``stamp_offset_s`` its own
    t_daq - t_camera from the stamp (None without an origin)."""

    lost_blocks: int = 0
    lost_samples: int = 0
    restart: bool = False
    warnings: list[str] = field(default_factory=list)
    clipped_samples: dict[str, int] = field(default_factory=dict)
    stamp_offset_s: float | None = None


class BlockCheck:
    """Checks a live AccelBlock stream block by block (see the module doc).

    ``expected_rate_hz``: the rate the DAQ is set to (0: the first block's rate, which every later block must
    keep); ``origin_ns``: the lab-clock origin of the camera time (``time_origin_unix_ns``); ``full_scale_mps2``:
    the sensors' range (0: unknown, no clipping check here; the detector still flags an impact whose peak sits
    flat at its extreme); ``max_stamp_jitter_s``: a block stamped further than this from the stamps' running
    offset is reported (the stamps then do not give the clock offset to better than that).
    """

    def __init__(self, expected_rate_hz: float = 0.0, origin_ns: int = 0, full_scale_mps2: float = 0.0,
                 max_stamp_jitter_s: float = 0.002) -> None:
        if not (math.isfinite(expected_rate_hz) and expected_rate_hz >= 0):
            raise AccelStreamRefused(f"accel_rate_hz must be a rate in Hz >= 0 (0 = the stream's), "
                                     f"got {expected_rate_hz}")
        if 0 < expected_rate_hz < MIN_RATE_HZ:
            raise AccelStreamRefused(f"accel_rate_hz {expected_rate_hz:g} Hz is below {MIN_RATE_HZ:g} Hz: an impact's "
                                     "ringing cannot be detected and timed at that rate")
        self.expected_rate_hz = float(expected_rate_hz)
        self.origin_ns = int(origin_ns)
        self.full_scale_mps2 = float(full_scale_mps2)
        self.max_stamp_jitter_s = float(max_stamp_jitter_s)
        self.rate_hz: float | None = None
        self.block_n: int | None = None
        self.blocks = 0
        self.lost_blocks = 0
        self.lost_samples = 0
        self._next_index: int | None = None
        self._next_sample: int | None = None
        self._next_t: float | None = None
        self._last_stamp_ns: int | None = None
        self._last_t_start = -math.inf
        self._offsets: deque[float] = deque(maxlen=STAMP_WINDOW)

    @property
    def stamp_offset_s(self) -> float | None:
        """t_daq - t_camera from the stamps: the median over the last :data:`STAMP_WINDOW` blocks (None before
        the first)."""
        return float(np.median(self._offsets)) if self._offsets else None

    @property
    def stamp_jitter_s(self) -> float:
        """Robust spread (1.4826 MAD, s) of the blocks' stamp offsets: how well the stamps give the offset."""
        if len(self._offsets) < 2:
            return math.nan
        a = np.asarray(self._offsets)
        return float(1.4826 * np.median(np.abs(a - np.median(a))))

    def check_block(self, msg: Any) -> BlockVerdict:
        """:meth:`check` of a ``vibro_msgs/AccelBlock`` message (any object with its fields): its header stamp
        read as ns on the lab clock."""
        return self.check(block_index=msg.block_index, first_sample_index=msg.first_sample_index,
                          sample_rate_hz=msg.sample_rate_hz, t_start_s=msg.t_start_s,
                          stamp_ns=int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec),
                          upper_ms2=msg.upper_ms2, lower_ms2=msg.lower_ms2)

    def check(self, *, block_index: int, first_sample_index: int, sample_rate_hz: float, t_start_s: float,
              stamp_ns: int, upper_ms2, lower_ms2) -> BlockVerdict:
        """The verdict on one block; :class:`AccelStreamRefused` for a block the stream may not carry."""
        rate = float(sample_rate_hz)
        n_up, n_lo = len(upper_ms2), len(lower_ms2)
        self._refuse_malformed(block_index, sample_rate_hz, (n_up, n_lo), t_start_s)
        out = BlockVerdict()
        if self._last_stamp_ns is not None and stamp_ns < self._last_stamp_ns:
            raise AccelStreamRefused(f"block {block_index}: header stamp {stamp_ns} ns is "
                                     f"{(self._last_stamp_ns - stamp_ns) / 1e6:.3f} ms before the previous block's: "
                                     "stamps must be the lab-clock time of each block's first sample, never going back")
        if self._next_index is not None:
            self._check_continuity(out, block_index=block_index, first_sample_index=first_sample_index,
                                   t_start_s=t_start_s, rate=rate, n_samples=n_up)
        self.rate_hz = rate
        if self.block_n is None:
            self.block_n = n_up
        self._next_index = int(block_index) + 1
        self._next_sample = int(first_sample_index) + n_up
        self._next_t = float(t_start_s) + n_up / rate
        self._last_stamp_ns = int(stamp_ns)
        self._last_t_start = float(t_start_s)
        self.blocks += 1
        self.lost_blocks += out.lost_blocks
        self.lost_samples += out.lost_samples
        self._check_stamp(out, block_index, t_start_s, stamp_ns)
        if self.full_scale_mps2 > 0:
            self._check_clipping(out, block_index, t_start_s, (upper_ms2, lower_ms2))
        return out

    def _refuse_malformed(self, block_index: int, sample_rate_hz: float, counts: tuple[int, int],
                          t_start_s: float) -> None:
        """:class:`AccelStreamRefused` for a block whose rate (Hz), sample counts (upper, lower) or start time
        (s) the stream cannot carry."""
        rate = float(sample_rate_hz)
        n_up, n_lo = counts
        if not (math.isfinite(rate) and rate > 0):
            raise AccelStreamRefused(f"block {block_index}: sample_rate_hz is {sample_rate_hz!r}, not a rate in Hz")
        if self.expected_rate_hz and abs(rate - self.expected_rate_hz) > 1e-6 * self.expected_rate_hz:
            raise AccelStreamRefused(f"block {block_index}: sample_rate_hz {rate:g} Hz but the DAQ is stated at "
                                     f"{self.expected_rate_hz:g} Hz (parameter accel_rate_hz): every time and impact "
                                     "would be off by their ratio; set the driver's rate or accel_rate_hz")
        if rate < MIN_RATE_HZ:
            raise AccelStreamRefused(f"block {block_index}: sample_rate_hz {rate:g} Hz is below {MIN_RATE_HZ:g} Hz: an "
                                     "impact's ringing cannot be detected and timed at that rate")
        if self.rate_hz is not None and abs(rate - self.rate_hz) > 1e-6 * self.rate_hz:
            raise AccelStreamRefused(f"block {block_index}: sample_rate_hz changed from {self.rate_hz:g} to "
                                     f"{rate:g} Hz within the stream; restart the graph after changing the DAQ's rate")
        if n_up != n_lo or n_up == 0:
            raise AccelStreamRefused(f"block {block_index}: upper_ms2 has {n_up} samples and lower_ms2 {n_lo}: a "
                                     "block holds the same (> 0) number of samples of both plates")
        if not math.isfinite(t_start_s):
            raise AccelStreamRefused(f"block {block_index}: t_start_s is {t_start_s!r}")

    def _check_continuity(self, out: BlockVerdict, *, block_index: int, first_sample_index: int, t_start_s: float,
                          rate: float, n_samples: int) -> None:
        """Lost blocks, samples lost or repeated inside the driver, and a changed block size, into ``out``
        (times s, rate Hz); :class:`AccelStreamRefused` for a start time (s) not after the block before's."""
        if t_start_s <= self._last_t_start:
            raise AccelStreamRefused(f"block {block_index}: t_start_s {t_start_s:.6f} s is not after the block "
                                     f"before's ({self._last_t_start:.6f} s): the DAQ time must grow")
        gap = int(block_index) - self._next_index
        late_samples = (t_start_s - self._next_t) * rate if self._next_t is not None else 0.0
        if gap > 0:
            out.lost_blocks = gap
            by_count = int(first_sample_index) - (self._next_sample or 0)  # the DAQ's own sample count
            by_time = max(int(round(late_samples)), gap * (self.block_n or 0))
            out.lost_samples = by_count if by_count > 0 else by_time
            out.restart = True
            out.warnings.append(
                f"accelerometer blocks {self._next_index}..{block_index - 1} lost ({gap} block(s), "
                f"{1e3 * out.lost_samples / rate:.1f} ms from t = {self._next_t:.5f} s DAQ time): impacts there "
                "are not detected")
        elif abs(late_samples) > CONTINUITY_SAMPLES:
            out.lost_samples = max(int(round(late_samples)), 0)
            out.restart = True
            out.warnings.append(
                f"accelerometer block {block_index} starts {late_samples:+.1f} samples from the end of block "
                f"{block_index - 1} (t_start_s {t_start_s:.6f} s, expected {self._next_t:.6f} s): samples lost "
                "or repeated inside the driver; the detection restarts there")
        if self.block_n is not None and n_samples != self.block_n:
            out.warnings.append(f"accelerometer block {block_index} holds {n_samples} samples, the stream's blocks "
                                f"{self.block_n}: a driver sends a fixed block size")

    def _check_stamp(self, out: BlockVerdict, block_index: int, t_start_s: float, stamp_ns: int) -> None:
        """The block's lab-clock offset (s) into ``out`` and the running list, with a warning when it lies more
        than the allowed jitter from the stream's."""
        offset = float(t_start_s) - (int(stamp_ns) - self.origin_ns) / 1e9
        ref = self.stamp_offset_s
        if ref is not None and abs(offset - ref) > self.max_stamp_jitter_s:
            out.warnings.append(f"accelerometer block {block_index} stamped {1e3 * (ref - offset):+.2f} ms from the "
                                f"stream's lab-clock offset (more than {1e3 * self.max_stamp_jitter_s:g} ms): is the "
                                "stamp the time of the block's first sample, on the lab clock?")
        self._offsets.append(offset)
        out.stamp_offset_s = offset

    def _check_clipping(self, out: BlockVerdict, block_index: int, t_start_s: float, channels: tuple) -> None:
        """Samples at or beyond the full scale (m/s^2) of each plate's channel (``channels``: upper, lower)."""
        for name, x in zip(("upper", "lower"), channels):
            k = int(np.count_nonzero(np.abs(np.asarray(x, float)) >= self.full_scale_mps2))
            if k:
                out.clipped_samples[name] = k
                out.warnings.append(f"the {name} plate's accelerometer clipped: {k} sample(s) at or beyond its "
                                    f"full scale {self.full_scale_mps2:g} m/s^2 in block {block_index} "
                                    f"(t = {t_start_s:.5f} s DAQ time): peaks and energies there are not "
                                    "trustworthy")


#: DIC impacts (and as many accelerometer impacts) the live clock fit keeps: about 6 s at two impacts per 22 Hz
#: cycle, so that a DAQ crystal's rate (a few 100 ppm: 0.5 ms over 1 s at 500 ppm) is fitted to a few ppm
LIVE_CLOCK_WINDOW = 256


class LiveClockOffset:
    """t_daq - t_camera of a live run: from the blocks' lab-clock stamps (:class:`BlockCheck`), refined from the
    impacts seen by both the camera and the accelerometers as ``vibro analyze`` refines it (the median of the
    matched differences, then offset + rate when the DAQ's clock drifts significantly against the camera's:
    :func:`vibro_fit.accel_impacts.refine_clock_offset`), seeded at the stamps' offset so that a regular motion
    cannot pull it a whole period away. The last ``window`` impacts of each clock are kept, so the fit follows a
    drift as they accumulate. ``tol_s``: how far a DIC impact may lie from an accelerometer impact to be matched
    (the stamps' uncertainty plus the DIC impact time's)."""

    def __init__(self, tol_s: float = 0.0005, window: int = LIVE_CLOCK_WINDOW) -> None:
        self.tol_s = float(tol_s)
        self.accel_daq_s: deque[float] = deque(maxlen=window)
        self.dic_cam_s: deque[float] = deque(maxlen=window)
        self.stamps_s: float | None = None
        self.refined: ClockOffset | None = None

    @property
    def _determined(self) -> bool:
        return self.refined is not None and self.refined.determined

    @property
    def offset_s(self) -> float | None:
        """The refined offset (s, at camera time :attr:`t_ref_s`) when determined, else the stamps'."""
        if self._determined:
            return self.refined.offset_s
        return self.stamps_s

    @property
    def rate_ppm(self) -> float:
        """How much faster the DAQ's clock runs than the camera's (ppm): the refined rate when determined and
        significant, else 0."""
        return float(self.refined.rate_ppm) if self._determined else 0.0

    @property
    def t_ref_s(self) -> float:
        """The camera time (s) at which :attr:`offset_s` holds (with a rate; 0 without a refined fit)."""
        return float(self.refined.t_ref_s) if self._determined else 0.0

    def to_camera_s(self, t_daq_s: float) -> float:
        """A DAQ-clock time (s) on the camera clock (s): with the refined offset and rate when determined, else
        minus the stamps' offset (unchanged before any stamp)."""
        if self._determined:
            return float(self.refined.line.camera_s(t_daq_s))
        return float(t_daq_s) - (self.stamps_s or 0.0)

    @property
    def source(self) -> str:
        if self._determined:
            rate = f", rate {self.refined.rate_ppm:+.1f} ppm" if self.refined.rate_ppm else ""
            return (f"impacts ({self.refined.n_matched} matched, residual {1e6 * self.refined.residual_std_s:.0f} us"
                    f"{rate})")
        return "stamps" if self.stamps_s is not None else "none"

    def add_accel(self, t_daq_s: float) -> None:
        self.accel_daq_s.append(float(t_daq_s))

    def add_dic(self, t_cam_s: float) -> None:
        self.dic_cam_s.append(float(t_cam_s))
        self.refine()

    def refine(self) -> ClockOffset | None:
        """Refit the relation from the impacts kept (seeded at the stamps' offset); the last fit, or None before
        the first stamp and the first impact of each clock."""
        if self.stamps_s is None or not self.accel_daq_s or not self.dic_cam_s:
            return self.refined
        self.refined = refine_clock_offset(list(self.accel_daq_s), list(self.dic_cam_s), self._seed_s(), self.tol_s)
        return self.refined

    def _seed_s(self) -> float:
        """The offset (s) the refinement starts from: the stamps', or the last determined fit's at the middle of the
        DIC impacts kept (with its rate, it has followed a drift the stamps' median lags behind)."""
        if not self._determined or not self.refined.rate_ppm:
            return float(self.stamps_s)
        mid = 0.5 * (self.dic_cam_s[0] + self.dic_cam_s[-1])
        return float(self.refined.line.daq_s(mid) - mid)
