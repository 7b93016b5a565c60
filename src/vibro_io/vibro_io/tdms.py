"""Read NI TDMS accelerometer files (npTDMS): two waveform channels of one group, in m/s^2.

rig.yaml names them (docs/recording-format.md)::

    accelerometers:
      file: accel.tdms
      group: accel            # the TDMS group holding both channels
      upper_channel: upper    # m/s^2, upper plate
      lower_channel: lower    # m/s^2, lower plate

Time comes from the DAQ itself, never from a column: sample i of a channel is at
``wf_start_offset + i * wf_increment`` seconds after ``wf_start_time``. When the camera's
wall-clock time of frame 0 is known (``camera.start_time_unix_s``, from rig.yaml or a CINE
header) the samples are placed on the camera clock by the two wall times:
``t_s = t0_s + (wf_start_time - start_time_unix_s) + wf_start_offset + i * wf_increment``;
otherwise the DAQ is taken to start at camera time 0 (up to the small unknown offset the
analysis estimates, as for accel.csv).
"""

from __future__ import annotations

import logging
import math
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

import numpy as np

from vibro_model.errors import AccelError

from .accel import AccelData, check_sample_rate, warn_if_clipped
from .rig import AccelConfig, CameraConfig

log = logging.getLogger(__name__)


@contextmanager
def _quiet_nptdms() -> Iterator[None]:
    """NpTDMS logs its own warnings for a short last segment; this module reports truncation itself."""
    loggers = [logging.getLogger(n) for n in ("nptdms", "nptdms.reader", "nptdms.tdms_segment")]
    levels = [lg.level for lg in loggers]
    for lg in loggers:
        lg.setLevel(logging.ERROR)
    try:
        yield
    finally:
        for lg, level in zip(loggers, levels):
            lg.setLevel(level)


def _unix_s(value: object) -> float | None:
    """A TDMS time property (numpy datetime64, UTC) as Unix seconds; None if absent or not a time."""
    if isinstance(value, np.datetime64):
        return float((value - np.datetime64(0, "ns")) / np.timedelta64(1, "ns")) * 1e-9
    return None


def _channel(path: Path, group: object, group_name: str, name: str):
    try:
        return group[name]
    except KeyError:
        names = ", ".join(c.name for c in group.channels()) or "none"
        raise AccelError(f"{path}: channel '{group_name}/{name}' not found (channels of group "
                         f"'{group_name}': {names})") from None


def load_tdms_accel(path: str | Path, cfg: AccelConfig, camera: CameraConfig | None = None,
                    camera_fps: float | None = None) -> AccelData:
    """The samples of ``cfg.group``/``cfg.upper_channel`` and ``cfg.lower_channel`` (m/s^2) on the camera clock (s).

    ``camera`` (rig.yaml's) places them by wall-clock time and gives the fps the rate must exceed;
    ``camera_fps`` alone only the latter.

    Refused (:class:`AccelError` naming file, channel and sample): an unreadable file, a missing
    group or channel, no ``wf_increment`` (not waveform data: the rate is unknown), channels with
    different rates, start times or lengths, fewer samples than the channel's ``wf_samples``
    (truncated file), a non-finite sample, or an implausible rate (:func:`check_sample_rate`).
    Clipped stretches are warned about (:func:`warn_if_clipped`).
    """
    from nptdms import TdmsFile

    path = Path(path)
    where = {}
    try:
        with _quiet_nptdms(), TdmsFile.open(str(path)) as tdms:
            try:
                group = tdms[cfg.group]
            except KeyError:
                names = ", ".join(g.name for g in tdms.groups()) or "none"
                raise AccelError(f"{path}: group '{cfg.group}' not found (groups: {names})") from None
            channels = {}
            for role, name in (("upper", cfg.upper_channel), ("lower", cfg.lower_channel)):
                channel = _channel(path, group, cfg.group, name)
                where[role] = f"{path}: channel '{cfg.group}/{name}'"
                channels[role] = (np.asarray(channel[:], dtype=float), dict(channel.properties))
    except AccelError:
        raise
    except Exception as exc:  # npTDMS raises ValueError, struct errors, OSError for a bad file
        raise AccelError(f"{path}: not a readable TDMS file ({type(exc).__name__}: {exc})") from None

    (upper, up_props), (lower, low_props) = channels["upper"], channels["lower"]
    dt = {}
    for role, props in (("upper", up_props), ("lower", low_props)):
        inc = props.get("wf_increment")
        if isinstance(inc, bool) or not isinstance(inc, (int, float)) or not math.isfinite(inc) or inc <= 0:
            raise AccelError(f"{where[role]}: property wf_increment (s per sample) missing or not positive "
                             f"({inc!r}): not waveform data, the sample rate is unknown")
        dt[role] = float(inc)
    if abs(dt["upper"] - dt["lower"]) > 1e-9 * dt["upper"]:
        raise AccelError(f"{path}: channels '{cfg.upper_channel}' and '{cfg.lower_channel}' have different "
                         f"sample intervals (wf_increment {dt['upper']:g} s and {dt['lower']:g} s)")
    starts = [_unix_s(up_props.get("wf_start_time")), _unix_s(low_props.get("wf_start_time"))]
    offsets = [float(p.get("wf_start_offset", 0.0) or 0.0) for p in (up_props, low_props)]
    if starts[0] != starts[1] or offsets[0] != offsets[1]:
        raise AccelError(f"{path}: channels '{cfg.upper_channel}' and '{cfg.lower_channel}' start at different "
                         "times (wf_start_time / wf_start_offset differ)")
    for role, values, props in (("upper", upper, up_props), ("lower", lower, low_props)):
        announced = props.get("wf_samples")
        if isinstance(announced, (int, np.integer)) and values.size < int(announced):
            raise AccelError(f"{where[role]}: {values.size} samples but wf_samples announces {int(announced)}: "
                             f"the file is truncated at sample {values.size}")
        bad = np.flatnonzero(~np.isfinite(values))
        if bad.size:
            raise AccelError(f"{where[role]}: sample {bad[0]}: non-finite value {values[bad[0]]}")
    if upper.size != lower.size:
        short, role = (lower, "lower") if lower.size < upper.size else (upper, "upper")
        raise AccelError(f"{where[role]}: {short.size} samples against {max(upper.size, lower.size)} in the other "
                         f"channel: the file is truncated (or the channels were recorded apart) at sample "
                         f"{short.size}")
    if upper.size < 2:
        raise AccelError(f"{path}: fewer than 2 samples in group '{cfg.group}'")
    check_sample_rate(1.0 / dt["upper"], f"{where['upper']} (wf_increment {dt['upper']:g} s)",
                      camera.fps if camera else camera_fps)
    for role, values in (("upper", upper), ("lower", lower)):
        warn_if_clipped(values, where[role])
    t_s = offsets[0] + np.arange(upper.size) * dt["upper"]
    if camera is not None and camera.start_time_unix_s is not None and starts[0] is not None:
        t_s = t_s + camera.t0_s + (starts[0] - camera.start_time_unix_s)
    return AccelData(t_s=t_s, upper_ms2=upper, lower_ms2=lower)
