"""Read NI TDMS accelerometer files (npTDMS): two waveform channels of one group, delivered in m/s^2.

rig.yaml names them (docs/recording-format.md)::

    accelerometers:
      file: accel.tdms
      group: accel            # the TDMS group holding both channels
      upper_channel: upper    # upper plate
      lower_channel: lower    # lower plate
      sensitivity_mv_per_g: 100   # only for channels recorded in V or mV

Each channel's unit is its own ``unit_string`` property (or ``NI_UnitDescription``, ``unit``):
m/s^2 is taken as is, g is multiplied by 9.80665 m/s^2, a voltage (V, mV) is converted with the
sensor's sensitivity (mV per g); anything else is refused. A channel without a unit is taken as
rig.yaml's ``accelerometers.unit``, else as m/s^2 with a warning.

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
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import numpy as np

from vibro_model.errors import AccelError

from .accel_checks import (
    MS2,
    VOLTAGE_UNITS,
    AccelData,
    canonical_unit,
    check_sample_rate,
    mps2_per_unit,
    warn_if_clipped,
)
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


#: Channel properties that may hold the unit of the samples, in order of precedence.
UNIT_PROPERTIES = ("unit_string", "NI_UnitDescription", "unit")


def recorded_unit(props: dict, where: str) -> tuple[str, str] | None:
    """(unit as recorded, property holding it) of a channel; None when it records no unit.

    Two unit properties that mean different units are refused (:class:`AccelError` naming ``where``).
    """
    found = [(name, props[name].strip()) for name in UNIT_PROPERTIES
             if isinstance(props.get(name), str) and props[name].strip()]
    if not found:
        return None
    if len({canonical_unit(text) or text for _, text in found}) > 1:
        shown = ", ".join(f"{name} {text!r}" for name, text in found)
        raise AccelError(f"{where}: the unit properties disagree ({shown}): which unit the samples are in is unknown")
    name, text = found[0]
    return text, name


def channel_scale(recorded: tuple[str, str] | None, cfg: AccelConfig, role: str, where: str
                  ) -> tuple[str, float, str]:
    """(unit as recorded, m/s^2 per unit, where the unit was read) for the ``upper`` or ``lower`` channel.

    Refused (:class:`AccelError` naming ``where`` and the unit): a unit that is no acceleration
    or voltage, a voltage without ``accelerometers.sensitivity_mv_per_g``, and a unit that
    contradicts rig.yaml's ``accelerometers.unit``.
    """
    if recorded is None:
        unit = cfg.unit or MS2
        source = "accelerometers.unit" if cfg.unit else "assumed"
        return unit, _factor(unit, cfg, role, where, unit), source
    text, prop = recorded
    unit = canonical_unit(text)
    if unit is None:
        raise AccelError(f"{where}: unit {text!r} ({prop}) is not one vibro reads: expected an acceleration "
                         "(m/s^2 or g) or the sensor's voltage (V or mV, with accelerometers.sensitivity_mv_per_g "
                         "in rig.yaml)")
    if cfg.unit is not None and cfg.unit != unit:
        raise AccelError(f"{where}: the file records unit {text!r} ({prop}) but rig.yaml's accelerometers.unit "
                         f"says {cfg.unit}: correct or remove that key")
    return text, _factor(unit, cfg, role, where, f"{text!r} ({prop})"), prop


def _factor(unit: str, cfg: AccelConfig, role: str, where: str, shown: str) -> float:
    """M/s^2 per ``unit`` for the ``role`` sensor; a voltage without a sensitivity is refused naming the key."""
    if unit in VOLTAGE_UNITS and cfg.sensitivity_mv_per_g is None:
        raise AccelError(f"{where}: unit {shown} is the sensor's voltage: add the sensor's sensitivity "
                         "(mV per g) to rig.yaml as accelerometers.sensitivity_mv_per_g (one number, or "
                         "{upper: .., lower: ..}) to convert it to m/s^2")
    sensitivity = cfg.sensitivity_mv_per_g.of(role) if unit in VOLTAGE_UNITS else None
    return mps2_per_unit(unit, sensitivity)


def _unit_source(sources: list[str]) -> str:
    """One unit source for both channels, or ``upper: S1, lower: S2`` when they differ."""
    return sources[0] if sources[0] == sources[1] else f"upper: {sources[0]}, lower: {sources[1]}"


def _warn_assumed(path: Path, cfg: AccelConfig, sources: list[str]) -> None:
    """One warning naming the channels without a unit that were taken as m/s^2."""
    names = [f"'{cfg.group}/{n}'" for n, s in zip((cfg.upper_channel, cfg.lower_channel), sources) if s == "assumed"]
    if names:
        log.warning("%s: channel%s %s record%s no unit (unit_string): taken as m/s^2; if the samples are in g or "
                    "volts, write accelerometers.unit (and sensitivity_mv_per_g) in rig.yaml",
                    path, "s" if len(names) > 1 else "", " and ".join(names), "" if len(names) > 1 else "s")


def load_tdms_accel(path: str | Path, cfg: AccelConfig, camera: CameraConfig | None = None,
                    camera_fps: float | None = None) -> AccelData:
    """The samples of ``cfg.group``/``cfg.upper_channel`` and ``cfg.lower_channel`` on the camera clock.

    Parameters
    ----------
    path : str or Path
        The NI TDMS file.
    cfg : AccelConfig
        rig.yaml's ``accelerometers`` block: group, channel names, unit, sensitivity.
    camera : CameraConfig, optional
        rig.yaml's camera: places the samples by wall-clock time and gives the frame rate the sample rate must
        exceed.
    camera_fps : float, optional
        The camera's frame rate (frames/s), when ``camera`` is not given.

    Returns
    -------
    AccelData
        Times (s, camera clock) and both channels in m/s^2 (+ up), with the unit read and the factor applied.

    Notes
    -----
    Each channel's unit (:func:`recorded_unit`) is converted to m/s^2 (:func:`channel_scale`);
    the returned :class:`AccelData` says which unit was read and the factor applied.

    ``camera`` (rig.yaml's) places them by wall-clock time and gives the fps the rate must exceed;
    ``camera_fps`` alone only the latter.

    Refused (:class:`AccelError` naming file, channel and sample): an unreadable file, a missing
    group or channel, a unit that is not m/s^2, g, or a voltage with a sensitivity, no
    ``wf_increment`` (not waveform data: the rate is unknown), channels with different rates,
    start times or lengths, fewer samples than the channel's ``wf_samples`` (truncated file),
    a non-finite sample, or an implausible rate (:func:`check_sample_rate`, naming wf_increment).
    Clipped stretches are warned about (:func:`warn_if_clipped`).
    """
    path = Path(path)
    chans = _read_channels(path, cfg)
    upper, lower = chans
    dt = _sample_interval(path, cfg, chans)
    start_unix_s, offset_s = _start_time(path, cfg, chans)
    _check_samples(path, cfg, chans)
    scales = [channel_scale(recorded_unit(ch.props, ch.where), cfg, ch.role, ch.where) for ch in chans]
    check_sample_rate(1.0 / dt, upper.where, camera.fps if camera else camera_fps, wf_increment_s=dt)
    for ch in chans:
        warn_if_clipped(ch.values, ch.where)
    _warn_assumed(path, cfg, [s[2] for s in scales])
    t_s = offset_s + np.arange(upper.values.size) * dt
    if camera is not None and camera.start_time_unix_s is not None and start_unix_s is not None:
        t_s = t_s + camera.t0_s + (start_unix_s - camera.start_time_unix_s)
    return AccelData(t_s=t_s, upper_ms2=upper.values * scales[0][1], lower_ms2=lower.values * scales[1][1],
                     source_units=(scales[0][0], scales[1][0]), mps2_per_source_unit=(scales[0][1], scales[1][1]),
                     unit_source=_unit_source([s[2] for s in scales]))


@dataclass(frozen=True)
class _TdmsChannel:
    """One accelerometer channel as read: its ``role`` (upper, lower), samples (file units), TDMS properties
    and ``where`` (file and channel, for messages)."""

    role: str
    values: np.ndarray
    props: dict
    where: str


def _read_channels(path: Path, cfg: AccelConfig) -> tuple[_TdmsChannel, _TdmsChannel]:
    """The upper and lower channels of ``cfg.group`` in the TDMS file ``path``; AccelError when unreadable."""
    from nptdms import TdmsFile

    channels = []
    try:
        with _quiet_nptdms(), TdmsFile.open(str(path)) as tdms:
            try:
                group = tdms[cfg.group]
            except KeyError:
                names = ", ".join(g.name for g in tdms.groups()) or "none"
                raise AccelError(f"{path}: group '{cfg.group}' not found (groups: {names})") from None
            for role, name in (("upper", cfg.upper_channel), ("lower", cfg.lower_channel)):
                channel = _channel(path, group, cfg.group, name)
                channels.append(_TdmsChannel(role, np.asarray(channel[:], dtype=float), dict(channel.properties),
                                             f"{path}: channel '{cfg.group}/{name}'"))
    except AccelError:
        raise
    except Exception as exc:  # npTDMS raises ValueError, struct errors, OSError for a bad file
        raise AccelError(f"{path}: not a readable TDMS file ({type(exc).__name__}: {exc})") from None
    return channels[0], channels[1]


def _sample_interval(path: Path, cfg: AccelConfig, chans: tuple[_TdmsChannel, _TdmsChannel]) -> float:
    """The channels' common sample interval (s, ``wf_increment``); AccelError when missing or different."""
    dt = {}
    for ch in chans:
        inc = ch.props.get("wf_increment")
        if isinstance(inc, bool) or not isinstance(inc, (int, float)) or not math.isfinite(inc) or inc <= 0:
            raise AccelError(f"{ch.where}: property wf_increment (s per sample) missing or not positive "
                             f"({inc!r}): not waveform data, the sample rate is unknown")
        dt[ch.role] = float(inc)
    if abs(dt["upper"] - dt["lower"]) > 1e-9 * dt["upper"]:
        raise AccelError(f"{path}: channels '{cfg.upper_channel}' and '{cfg.lower_channel}' have different "
                         f"sample intervals (wf_increment {dt['upper']:g} s and {dt['lower']:g} s)")
    return dt["upper"]


def _start_time(path: Path, cfg: AccelConfig, chans: tuple[_TdmsChannel, _TdmsChannel]) -> tuple[float | None, float]:
    """The channels' common (wall-clock start, Unix s or None; start offset, s); AccelError when they differ."""
    starts = [_unix_s(ch.props.get("wf_start_time")) for ch in chans]
    offsets = [float(ch.props.get("wf_start_offset", 0.0) or 0.0) for ch in chans]
    if starts[0] != starts[1] or offsets[0] != offsets[1]:
        raise AccelError(f"{path}: channels '{cfg.upper_channel}' and '{cfg.lower_channel}' start at different "
                         "times (wf_start_time / wf_start_offset differ)")
    return starts[0], offsets[0]


def _check_samples(path: Path, cfg: AccelConfig, chans: tuple[_TdmsChannel, _TdmsChannel]) -> None:
    """AccelError for a truncated channel, a non-finite sample, channels of different lengths or < 2 samples."""
    for ch in chans:
        announced = ch.props.get("wf_samples")
        if isinstance(announced, (int, np.integer)) and ch.values.size < int(announced):
            raise AccelError(f"{ch.where}: {ch.values.size} samples but wf_samples announces {int(announced)}: "
                             f"the file is truncated at sample {ch.values.size}")
        bad = np.flatnonzero(~np.isfinite(ch.values))
        if bad.size:
            raise AccelError(f"{ch.where}: sample {bad[0]}: non-finite value {ch.values[bad[0]]}")
    upper, lower = chans
    if upper.values.size != lower.values.size:
        short = lower if lower.values.size < upper.values.size else upper
        raise AccelError(f"{short.where}: {short.values.size} samples against "
                         f"{max(upper.values.size, lower.values.size)} in the other channel: the file is truncated "
                         f"(or the channels were recorded apart) at sample {short.values.size}")
    if upper.values.size < 2:
        raise AccelError(f"{path}: fewer than 2 samples in group '{cfg.group}'")
