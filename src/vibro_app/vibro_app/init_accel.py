"""``vibro init``: the accelerometer file beside the video, named in rig.yaml's ``accelerometers`` block.

A lab's recording folder holds the camera file and the DAQ's file (accel.csv, or an NI TDMS). rig.yaml must name
the file and which column or channel is which plate, else ``vibro analyze`` reads the video alone. Without this,
a lab that typed only the ball's diameter and the gap got a video-only analysis with exit code 0. So init looks:

- no accelerometer file in the folder: no block (video only), said;
- one file (``accel.csv`` or a ``*.tdms``), or the one ``--accel`` names: its time column (CSV) and the upper and
  lower plate's column or channel, by name (``upper``/``top`` and ``lower``/``bottom``) or as ``--accel-upper``
  and ``--accel-lower`` give them; a name that fits no column or channel, or two, is refused with the names there
  are, so that the user picks (nothing is guessed);
- several files and no ``--accel``: refused, naming them; ``--no-accel``: video only, as asked.

The units: a TDMS channel's ``unit_string`` property is read by the loader; a CSV is taken as m/s^2 unless its
column names end in ``_g``, ``_v`` or ``_mv`` (then ``unit`` is written; volts also need the sensitivity, which
only the user knows: refused with the key to set).
"""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path

from vibro_model.errors import RecordingError

UPPER_WORDS = ("upper", "top")
LOWER_WORDS = ("lower", "bottom")
TIME_WORDS = ("time", "t_s")
#: CSV column suffix -> rig.yaml accelerometers.unit
UNIT_SUFFIXES = {"_g": "g", "_v": "V", "_mv": "mV"}


@dataclass(frozen=True, kw_only=True)
class AccelChoice:
    """The ``accelerometers`` block init writes (``lines``: YAML, without the key line) and what it says of it."""

    file: str
    lines: tuple[str, ...]
    note: str

    def yaml(self) -> str:
        return "accelerometers:               # " + self.note + "\n" + "".join(f"  {line}\n" for line in self.lines)


@dataclass(frozen=True, kw_only=True)
class AccelRequest:
    """What the user said on the command line: ``file`` (``--accel``), ``upper``/``lower`` column or channel
    names (``--accel-upper``/``--accel-lower``), ``none`` (``--no-accel``)."""

    file: str | None = None
    upper: str | None = None
    lower: str | None = None
    none: bool = False


def accelerometer_files(folder: Path) -> list[Path]:
    """accel.csv and every ``*.tdms`` (any case) in ``folder``, sorted."""
    return sorted(p for p in folder.iterdir() if p.is_file() and (p.name == "accel.csv"
                                                                  or p.suffix.lower() == ".tdms"))


def choose_accel(folder: Path, request: AccelRequest) -> AccelChoice | None:
    """The accelerometers block for the recording in ``folder`` (module doc), or None for a video-only one;
    :class:`RecordingError` when the choice is not the file's to make."""
    if request.none:
        return None
    if request.file is not None:
        path = folder / request.file
        if not path.is_file():
            raise RecordingError(f"--accel {request.file}: no such file in {folder}")
        files = [path]
    else:
        files = accelerometer_files(folder)
    if not files:
        return None
    if len(files) > 1:
        raise RecordingError(f"{folder}: several accelerometer files ({', '.join(p.name for p in files)}): name the "
                             "one of this take with --accel FILE (or --no-accel for a video-only analysis)")
    path = files[0]
    return _tdms_choice(path, request) if path.suffix.lower() == ".tdms" else _csv_choice(path, request)


def _pick(names: list[str], given: str | None, words: tuple[str, ...], what: str, where: str, *,
          how_to_say: str = "name it so") -> str:
    """The one name of ``names`` that is ``given``, or else the one containing one of ``words`` (any case);
    refused with ``how_to_say`` (the option that names it) when none or several do."""
    if given is not None:
        if given not in names:
            raise RecordingError(f"{where}: no {what} '{given}' (there are: {', '.join(names)})")
        return given
    found = [n for n in names if any(w in n.lower() for w in words)]
    if len(found) != 1:
        how = "none" if not found else f"{len(found)} ({', '.join(found)})"
        raise RecordingError(f"{where}: which is the {what}? {how} of {', '.join(names)} has "
                             f"{'/'.join(words)} in its name: {how_to_say}")
    return found[0]


def _csv_choice(path: Path, request: AccelRequest) -> AccelChoice:
    """The block of an accel.csv: its time, upper and lower columns, and their unit (module doc)."""
    with path.open(newline="", encoding="utf-8", errors="replace") as fh:
        header = next(csv.reader(fh), [])
    names = [h.strip() for h in header if h.strip()]
    if len(names) < 3:
        raise RecordingError(f"{path}: a header of at least 3 columns (time, upper, lower) expected, got {header}")
    time_col = _pick(names, None, TIME_WORDS, "time column", str(path))
    upper = _pick(names, request.upper, UPPER_WORDS, "upper plate's column", str(path),
                  how_to_say="give it with --accel-upper")
    lower = _pick(names, request.lower, LOWER_WORDS, "lower plate's column", str(path),
                  how_to_say="give it with --accel-lower")
    lines = [f"file: {path.name}", f"time_column: {time_col}", f"upper_column: {upper}", f"lower_column: {lower}"]
    units = {UNIT_SUFFIXES[s] for c in (upper, lower) for s in UNIT_SUFFIXES if c.lower().endswith(s)}
    if len(units) > 1:
        raise RecordingError(f"{path}: the columns {upper} and {lower} name different units; set "
                             "accelerometers.unit in rig.yaml by hand")
    if units:
        unit = units.pop()
        if unit in ("V", "mV"):
            raise RecordingError(f"{path}: the columns are in {unit}: rig.yaml needs accelerometers.unit {unit} and "
                                 "accelerometers.sensitivity_mv_per_g (the sensors' calibration), which init cannot "
                                 "know; write the block by hand (docs/recording-format.md)")
        lines.append(f"unit: {unit}")
    return AccelChoice(file=path.name, lines=tuple(lines), note=f"found beside the video: {path.name}")


def _tdms_choice(path: Path, request: AccelRequest) -> AccelChoice:
    """The block of a TDMS file: the group and the upper and lower plate's channels (module doc)."""
    from nptdms import TdmsFile

    try:
        meta = TdmsFile.read_metadata(str(path))
    except Exception as exc:  # noqa: BLE001 - npTDMS raises many kinds on a damaged file: named, not a trace
        raise RecordingError(f"{path}: not a readable TDMS file ({type(exc).__name__}: {exc})") from None
    channels = [(g.name, c.name) for g in meta.groups() for c in g.channels()]
    if not channels:
        raise RecordingError(f"{path}: no channel in the TDMS file")
    labels = [c for _, c in channels]
    upper = _pick(labels, request.upper, UPPER_WORDS, "upper plate's channel", str(path),
                  how_to_say="give it with --accel-upper")
    lower = _pick(labels, request.lower, LOWER_WORDS, "lower plate's channel", str(path),
                  how_to_say="give it with --accel-lower")
    groups = {g for g, c in channels if c in (upper, lower)}
    if len(groups) != 1 or labels.count(upper) > 1 or labels.count(lower) > 1:
        raise RecordingError(f"{path}: the channels {upper} and {lower} are not one group's "
                             f"({', '.join(f'{g}/{c}' for g, c in channels)}); write the block by hand "
                             "(docs/recording-format.md)")
    lines = [f"file: {path.name}", f"group: {groups.pop()}", f"upper_channel: {upper}", f"lower_channel: {lower}"]
    return AccelChoice(file=path.name, lines=tuple(lines), note=f"found beside the video: {path.name}")
