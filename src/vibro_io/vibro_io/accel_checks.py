"""Accelerometer samples and what accel.csv and accel.tdms share: units, sample-rate and clipping checks.

The samples are always delivered in m/s^2. A file may hold them in m/s^2, in g (standard
gravity, :data:`STANDARD_GRAVITY_MPS2`) or as the sensor's output voltage (V or mV), which the
sensor's sensitivity (mV per g, rig.yaml's ``accelerometers.sensitivity_mv_per_g``) turns into
an acceleration: ``a_mps2 = u_V * 1000 / sensitivity_mv_per_g * 9.80665``.
"""

from __future__ import annotations

import logging
import re
from dataclasses import dataclass

import numpy as np

from vibro_model.errors import AccelError

log = logging.getLogger(__name__)

#: Standard gravity g_n (m/s^2), the "g" of accelerometer data sheets (exact by definition).
STANDARD_GRAVITY_MPS2 = 9.80665

#: Canonical unit names: what rig.yaml's ``accelerometers.unit`` and a TDMS unit string may mean.
MS2, G, VOLT, MILLIVOLT = "m/s^2", "g", "V", "mV"
#: Units that are a voltage: they need the sensor's sensitivity (mV per g).
VOLTAGE_UNITS = (VOLT, MILLIVOLT)
#: mV per unit of each voltage unit.
_MV_PER_UNIT = {VOLT: 1000.0, MILLIVOLT: 1.0}

_SPELLINGS = {
    MS2: ("m/s^2", "m/s2", "ms^-2", "m*s^-2", "m.s^-2", "m\u00b7s^-2", "ms-2", "m/sec^2", "m/s/s",
          "meterspersecondsquared", "metrespersecondsquared", "meterspersecond^2"),
    G: ("g", "g0", "gn", "g_0", "g_n", "gs", "g's"),
    VOLT: ("v", "volt", "volts"),
    MILLIVOLT: ("mv", "millivolt", "millivolts"),
}
_CANONICAL = {spelling: unit for unit, spellings in _SPELLINGS.items() for spelling in spellings}


def canonical_unit(text: str) -> str | None:
    """The canonical unit (:data:`MS2`, :data:`G`, :data:`VOLT`, :data:`MILLIVOLT`) a unit string means, else None.

    Case, blanks, parentheses, ``**`` for ``^`` and a superscript two are ignored:
    ``m/s²``, ``M/S^2``, ``m s^-2``, ``m/(s^2)``, ``Volts``, ``mV`` and ``gn`` are all recognised.
    """
    key = re.sub(r"[\s()]", "", text.strip().lower()).replace("\u00b2", "^2").replace("**", "^")
    return _CANONICAL.get(key)


def mps2_per_unit(unit: str, sensitivity_mv_per_g: float | None = None) -> float:
    """Factor that turns samples in a canonical unit into m/s^2.

    Parameters
    ----------
    unit : str
        A canonical unit (:func:`canonical_unit`): :data:`MS2`, :data:`G`, :data:`VOLT` or :data:`MILLIVOLT`.
    sensitivity_mv_per_g : float, optional
        The sensor's sensitivity (mV per g, > 0); required for a voltage unit.

    Returns
    -------
    float
        m/s^2 per ``unit``.

    Raises
    ------
    ValueError
        A voltage unit without a positive sensitivity, or a unit that is not canonical.
    """
    if unit == MS2:
        return 1.0
    if unit == G:
        return STANDARD_GRAVITY_MPS2
    if unit in VOLTAGE_UNITS:
        if sensitivity_mv_per_g is None:
            raise ValueError(f"a sensitivity (mV per g) is needed to convert {unit} to m/s^2")
        return _MV_PER_UNIT[unit] / sensitivity_mv_per_g * STANDARD_GRAVITY_MPS2
    raise ValueError(f"unknown unit {unit!r}")


@dataclass
class AccelData:
    """Samples on one clock: ``t_s`` (s, increasing), ``upper_ms2`` and ``lower_ms2`` (m/s^2).

    How the file gave them (what ``vibro info`` reports):

    - ``source_units``: the upper and lower channel's unit as recorded, verbatim (a TDMS
      channel's unit string, e.g. ``Volts``; rig.yaml's ``accelerometers.unit`` for accel.csv);
    - ``mps2_per_source_unit``: the factor (m/s^2 per source unit) applied to each channel,
      1 for m/s^2, 9.80665 for g, ``1000 / sensitivity_mv_per_g * 9.80665`` for V;
    - ``unit_source``: where the unit was read: the TDMS property (``unit_string``,
      ``NI_UnitDescription`` or ``unit``), ``accelerometers.unit`` (rig.yaml), ``default``
      (accel.csv without that key: m/s^2 by the recording format) or ``assumed`` (a TDMS
      channel without a unit: taken as m/s^2, with a warning).
    """

    t_s: np.ndarray
    upper_ms2: np.ndarray
    lower_ms2: np.ndarray
    source_units: tuple[str, str] = (MS2, MS2)
    mps2_per_source_unit: tuple[float, float] = (1.0, 1.0)
    unit_source: str = "default"

    @property
    def sample_rate_hz(self) -> float:
        """Median sample rate (Hz)."""
        return float(1.0 / np.median(np.diff(self.t_s)))

    @property
    def source_unit(self) -> str:
        """The unit the file recorded (both channels'), or ``upper: U1, lower: U2`` when they differ."""
        upper, lower = self.source_units
        return upper if upper == lower else f"upper: {upper}, lower: {lower}"

    def __len__(self) -> int:
        return int(self.t_s.size)


# Impacts are located in the accelerometer signal to a fraction of a camera frame: the DAQ must
# sample at several kHz and faster than the camera. Below this floor the time column is misread.
MIN_SAMPLE_RATE_HZ = 2_000.0
MAX_SAMPLE_RATE_HZ = 10e6  # beyond any DAQ for accelerometers


def _rate_need(low_hz: float, camera_fps: float | None, rate_hz: float) -> str:
    """What an accelerometer DAQ for impacts must do, for the message of :func:`check_sample_rate`."""
    if rate_hz > MAX_SAMPLE_RATE_HZ:
        return f"no accelerometer DAQ samples faster than {MAX_SAMPLE_RATE_HZ:g} Hz"
    return (f"an accelerometer for impacts samples at several kHz (at least {low_hz:g} Hz"
            + (f", faster than the camera's {camera_fps:g} fps" if camera_fps else "") + ")")


def _time_column_hint(rate_hz: float, low_hz: float) -> str:
    """The likely misreading of a CSV time column (a sample number, milliseconds, microseconds), or ''."""
    if rate_hz == 1.0:
        return "; samples are 1 apart: is the column a sample number instead of seconds?"
    if rate_hz < low_hz:
        for factor, unit in ((1e3, "milliseconds"), (1e6, "microseconds")):
            if low_hz <= rate_hz * factor <= MAX_SAMPLE_RATE_HZ:
                return (f"; read as {unit} it would be {rate_hz * factor:g} Hz: "
                        f"is the time in {unit} instead of seconds?")
    return ""


def check_sample_rate(rate_hz: float, where: str, camera_fps: float | None = None,
                      wf_increment_s: float | None = None) -> None:
    """Refuse a sample rate no accelerometer DAQ for impacts has.

    Parameters
    ----------
    rate_hz : float
        The sample rate (Hz) implied by the file.
    where : str
        The file (and column or channel) named in the message.
    camera_fps : float, optional
        The camera's frame rate (frames/s): the rate must exceed it.
    wf_increment_s : float, optional
        A TDMS channel's own sample spacing (s per sample), named in the message instead of a time column.

    Raises
    ------
    AccelError
        A rate outside the plausible range, naming ``where`` (and the likely unit mistake).

    Notes
    -----
    The plausible range is [max(MIN_SAMPLE_RATE_HZ, camera_fps), MAX_SAMPLE_RATE_HZ]: impacts
    need several kHz, and more than the camera's frame rate (fps).

    Without ``wf_increment_s`` the rate comes from a CSV time column read as seconds: a rate
    that becomes plausible when multiplied by 1000 or 1e6 means the column holds milliseconds
    or microseconds, and the message says so. With it (s per sample, a TDMS channel's own time
    base) the message names that time base instead: a TDMS has no time column to misread.
    """
    low = max(MIN_SAMPLE_RATE_HZ, camera_fps or 0.0)
    if low <= rate_hz <= MAX_SAMPLE_RATE_HZ:
        return
    need = _rate_need(low, camera_fps, rate_hz)
    if wf_increment_s is not None:
        advice = "; record at a higher rate" if rate_hz < low else ""
        raise AccelError(f"{where}: the DAQ's time base, wf_increment {wf_increment_s:g} s per sample, gives "
                         f"{rate_hz:g} samples/s, but {need}{advice}")
    raise AccelError(f"{where}: the time column (seconds) implies {rate_hz:g} samples/s, but {need}"
                     f"{_time_column_hint(rate_hz, low)}")


#: This many consecutive samples or more at a channel's extreme value look like a saturated ADC/amplifier.
CLIP_RUN_SAMPLES = 3


def warn_if_clipped(values: np.ndarray, where: str) -> int:
    """Warn when the signal sits at its maximum or minimum for CLIP_RUN_SAMPLES samples or more in a row.

    A saturated sensor, amplifier or DAQ range flattens the impact peaks.

    Parameters
    ----------
    values : numpy.ndarray
        One channel's samples (any unit: only their extremes are compared).
    where : str
        The file and channel named in the warning (with the first flat sample's index).

    Returns
    -------
    int
        The number of flat runs at the extremes (0: not clipped).
    """
    runs = 0
    first = None
    for extreme in (values.max(initial=-np.inf), values.min(initial=np.inf)):
        at = np.concatenate(([0], (values == extreme).astype(np.int8), [0]))
        edges = np.diff(at)
        starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
        long = starts[(ends - starts) >= CLIP_RUN_SAMPLES]
        runs += long.size
        if long.size and (first is None or long[0] < first[0]):
            first = (int(long[0]), float(extreme))
    if first is not None:
        log.warning("%s: clipped? %d stretch(es) of >= %d samples sit at the signal's extreme value, first at "
                    "sample %d (value %g): a saturated sensor or DAQ range flattens impact peaks; check the range",
                    where, runs, CLIP_RUN_SAMPLES, first[0], first[1])
    return runs

