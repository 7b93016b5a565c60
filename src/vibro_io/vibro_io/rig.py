"""Read and validate ``rig.yaml`` (see docs/recording-format.md).

Conventions: lengths in the YAML are millimetres or pixels as their key names say,
masses in kg, moduli in Pa. Every error names the file and the dotted key.
"""

from __future__ import annotations

import difflib
import hashlib
import logging
import math
import os
import re
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Iterable, Mapping

import yaml

from vibro_model.constants import axial_gravity_mps2
from vibro_model.errors import FrameError, RigError

from .accel_checks import VOLTAGE_UNITS, canonical_unit
from .camera_calibration import calibration_of_rig
from .camera_files import CAMERA_FILE_SUFFIXES, merge_camera_header, open_camera_file
from .frames_source import find_frames_source
from .paths import relative_name_problem

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Roi:
    """Axis-aligned rectangle in pixels: column x, row y, width w, height h."""

    x: int
    y: int
    w: int
    h: int

    def as_list(self) -> list[int]:
        return [self.x, self.y, self.w, self.h]


@dataclass(frozen=True)
class CameraConfig:
    fps: float
    t0_s: float
    mm_per_px: float
    #: Wall-clock time (Unix s, UTC) of frame 0, when rig.yaml gives it (optional): the lab clock of the
    #: node graph's header stamps (vibro_ros.lab_clock). None: vibro graph uses its own start time.
    start_time_unix_s: float | None = None
    #: Relative 1-sigma of ``mm_per_px`` (e.g. 0.0013 for 0.13 %), when rig.yaml gives it (optional; ``vibro
    #: init`` writes its own). A scale error scales every length and acceleration alike: the flights' gravity
    #: then looks tilted, so the discrepancy analysis claims no tilt within 3 of these sigmas. None: unknown.
    mm_per_px_rel_std: float | None = None
    #: The camera's intrinsic calibration, a ROS camera_info YAML named relative to rig.yaml (optional;
    #: :mod:`vibro_io.camera_calibration`): tracked positions are undistorted with it before the scale applies.
    calibration: str | None = None

    def frame_time_s(self, index: int) -> float:
        """Time (s) of frame ``index``: t0_s + index / fps."""
        return self.t0_s + index / self.fps


@dataclass(frozen=True)
class BallConfig:
    mass_kg: float
    diameter_mm: float
    youngs_modulus_pa: float
    poisson_ratio: float


@dataclass(frozen=True)
class StructureConfig:
    gap_mm: float
    mass_kg: float
    youngs_modulus_pa: float
    poisson_ratio: float


@dataclass(frozen=True)
class ExcitationConfig:
    frequency_hz: float
    #: nominal shaker acceleration amplitude (m/s^2), when rig.yaml gives it (optional): what a campaign
    #: sweeps beside the frequency; vibro identifies the structure's actual motion itself
    acceleration_mps2: float | None = None


#: rig.yaml ``setup.axis_tilt_deg``'s range: 0 the motion axis vertical (the default), 90 horizontal
AXIS_TILT_RANGE_DEG = (0.0, 90.0)


@dataclass(frozen=True)
class SetupConfig:
    """How the rig is mounted (rig.yaml ``setup``, optional): ``axis_tilt_deg``, the motion axis from vertical
    (0 vertical, the default; 45 tilted; 90 horizontal: the paper's Fig. 11 study). A declared orientation is
    a known property of the rig, not a finding: gravity along the axis is g cos(axis_tilt_deg)
    (:attr:`g_axis_mps2`), what the flights fall at and what friction per flight (Eq. 17) is measured against."""

    axis_tilt_deg: float = 0.0

    @property
    def g_axis_mps2(self) -> float:
        """Gravity along the motion axis, g cos(axis_tilt_deg) (m/s^2; 0 for a horizontal axis)."""
        return axial_gravity_mps2(self.axis_tilt_deg)


#: how the ball is tracked (rig.yaml ``dic.ball_method``): ``mesh``, the DIC mesh of subsets on a speckled
#: ball (``ball_roi`` inside the disc); ``outline``, a plain ball by its outline (``ball_roi`` a box around the
#: whole ball in frame 0, with a margin; :mod:`vibro_dic.outline`). Absent from rig.yaml: the texture check of frame
#: 0's ball ROI chooses (:func:`vibro_dic.ball_method.choose_ball_method`: plain -> outline, speckled -> mesh)
BALL_METHODS = ("mesh", "outline")


@dataclass(frozen=True)
class DicConfig:
    subset_px: int
    mesh_step_px: int
    ball_roi: Roi
    structure_roi: Roi
    ball_method: str = "mesh"
    #: False when rig.yaml does not name ``dic.ball_method``: ``ball_method`` is then only the default, and the
    #: tracker chooses by the texture of frame 0's ball ROI (:func:`vibro_dic.ball_method.choose_ball_method`)
    ball_method_named: bool = field(default=True, compare=False)


@dataclass(frozen=True)
class AccelSensitivity:
    """Sensitivity (mV per g, g = 9.80665 m/s^2) of the upper and of the lower plate's accelerometer."""

    upper_mv_per_g: float
    lower_mv_per_g: float

    def of(self, role: str) -> float:
        """The sensitivity (mV per g) of the ``upper`` or ``lower`` sensor."""
        return self.upper_mv_per_g if role == "upper" else self.lower_mv_per_g

    def to_yaml(self) -> float | dict[str, float]:
        """One number when both sensors have it, else ``{upper: .., lower: ..}`` (mV per g), as rig.yaml writes it."""
        if self.upper_mv_per_g == self.lower_mv_per_g:
            return self.upper_mv_per_g
        return {"upper": self.upper_mv_per_g, "lower": self.lower_mv_per_g}


@dataclass(frozen=True, kw_only=True)
class AccelConfig:
    """Where the accelerometer samples are: CSV columns, or (``file`` ending .tdms) TDMS group and channels.

    ``unit`` (canonical: ``m/s^2``, ``g``, ``V``, ``mV``; None when rig.yaml leaves it out) is
    what accel.csv's values are (None: m/s^2); for a TDMS, the channels' own unit string rules
    and ``unit`` only fills in for a channel without one. ``sensitivity_mv_per_g`` (mV per g)
    converts a voltage (V or mV) into m/s^2.
    """

    file: str
    time_column: str | None = None
    upper_column: str | None = None
    lower_column: str | None = None
    group: str | None = None  # TDMS only: the group holding the two channels
    upper_channel: str | None = None  # TDMS only
    lower_channel: str | None = None  # TDMS only
    unit: str | None = None
    sensitivity_mv_per_g: AccelSensitivity | None = None

    @property
    def is_tdms(self) -> bool:
        return self.file.lower().endswith(".tdms")

    def to_dict(self) -> dict[str, Any]:
        """The YAML mapping of this block (keys left out of rig.yaml omitted)."""
        out = {k: v for k, v in asdict(self).items() if v is not None}
        if self.sensitivity_mv_per_g is not None:
            out["sensitivity_mv_per_g"] = self.sensitivity_mv_per_g.to_yaml()
        return out


@dataclass(frozen=True)
class RigConfig:
    """Everything rig.yaml says; ``path`` is the file it was read from (or None)."""

    camera: CameraConfig
    ball: BallConfig
    structure: StructureConfig
    excitation: ExcitationConfig
    dic: DicConfig
    accelerometers: AccelConfig | None = None
    path: str | None = None
    setup: SetupConfig = field(default_factory=SetupConfig)

    @property
    def g_axis_mps2(self) -> float:
        """Gravity along the motion axis as mounted (m/s^2): g cos(setup.axis_tilt_deg)."""
        return self.setup.g_axis_mps2

    @property
    def free_play_mm(self) -> float:
        """Half the travel of the ball centre between the plates, b = (gap - diameter) / 2 (mm)."""
        return 0.5 * (self.structure.gap_mm - self.ball.diameter_mm)

    def to_dict(self) -> dict[str, Any]:
        """The YAML mapping of this rig (inverse of :func:`parse_rig`)."""
        out = asdict(self)
        out.pop("path")
        out["dic"]["ball_roi"] = self.dic.ball_roi.as_list()
        out["dic"]["structure_roi"] = self.dic.structure_roi.as_list()
        out["dic"].pop("ball_method_named")
        if self.dic.ball_method == "mesh" or not self.dic.ball_method_named:  # the default: files stay as they were
            out["dic"].pop("ball_method")
        if self.accelerometers is None:
            out.pop("accelerometers")
        else:
            out["accelerometers"] = self.accelerometers.to_dict()
        if self.camera.start_time_unix_s is None:
            out["camera"].pop("start_time_unix_s")
        if self.camera.mm_per_px_rel_std is None:
            out["camera"].pop("mm_per_px_rel_std")
        if self.camera.calibration is None:
            out["camera"].pop("calibration")
        if self.excitation.acceleration_mps2 is None:
            out["excitation"].pop("acceleration_mps2")
        setup = out.pop("setup")   # optional: written only when it says more than the default (vertical)
        if self.setup != SetupConfig():
            out = {**{k: v for k, v in out.items() if k in ("camera",)}, "setup": setup,
                   **{k: v for k, v in out.items() if k not in ("camera",)}}
        return out


# PyYAML's YAML 1.1 resolver reads "3.1e11" and "1e-4" as strings; people write them.
_FLOAT_RE = re.compile(
    r"""^[-+]?(?:
        (?:[0-9][0-9_]*)\.[0-9_]*(?:[eE][-+]?[0-9]+)?
       |\.[0-9_]+(?:[eE][-+]?[0-9]+)?
       |[0-9][0-9_]*[eE][-+]?[0-9]+
       |\.(?:inf|Inf|INF)
       |\.(?:nan|NaN|NAN))$""",
    re.X,
)


class DuplicateKeyError(yaml.YAMLError):
    """A mapping key written twice in one YAML mapping."""


class _RigLoader(yaml.SafeLoader):
    """SafeLoader that reads scientific notation without a dot as a float and refuses duplicate keys.

    PyYAML keeps the last of two equal keys in a mapping without a word; a rig.yaml with
    ``fps:`` twice would silently use the second. Every mapping, at any depth, is checked.
    """

    def get_single_data(self) -> Any:
        node = self.get_single_node()
        if node is None:
            return None
        self.check_unique_keys(node, "")
        return self.construct_document(node)

    def check_unique_keys(self, node: yaml.Node, path: str) -> None:
        """Raise :class:`DuplicateKeyError` for a mapping key that appears twice (lines are 1-based)."""
        if isinstance(node, yaml.SequenceNode):
            for i, item in enumerate(node.value):
                self.check_unique_keys(item, f"{path}[{i}]")
            return
        if not isinstance(node, yaml.MappingNode):
            return
        first_line: dict[Any, int] = {}
        for key_node, value_node in node.value:
            if key_node.tag == "tag:yaml.org,2002:merge":
                continue
            key = self.construct_object(key_node, deep=True)
            name = f"{path}.{key}" if path else str(key)
            line = key_node.start_mark.line + 1
            try:
                if key in first_line:
                    raise DuplicateKeyError(f"key '{name}' appears twice, on lines {first_line[key]} and {line}; "
                                            "keep one (YAML would silently use the last)")
                first_line[key] = line
            except TypeError:  # an unhashable key: the constructor reports it
                continue
            self.check_unique_keys(value_node, name)


_RigLoader.yaml_implicit_resolvers = {
    k: [r for r in v if r[0] != "tag:yaml.org,2002:float"]
    for k, v in yaml.SafeLoader.yaml_implicit_resolvers.items()
}
_RigLoader.add_implicit_resolver("tag:yaml.org,2002:float", _FLOAT_RE, list("-+0123456789."))


_SCHEMA: dict[str, dict[str, str]] = {
    "camera": {"fps": "pos", "t0_s": "float", "mm_per_px": "pos"},
    "ball": {"mass_kg": "pos", "diameter_mm": "pos", "youngs_modulus_pa": "pos", "poisson_ratio": "poisson"},
    "structure": {"gap_mm": "pos", "mass_kg": "pos", "youngs_modulus_pa": "pos", "poisson_ratio": "poisson"},
    "excitation": {"frequency_hz": "pos"},
    "dic": {"subset_px": "odd", "mesh_step_px": "posint", "ball_roi": "roi", "structure_roi": "roi"},
}
_ACCEL_SCHEMA = {"file": "relpath", "time_column": "str", "upper_column": "str", "lower_column": "str"}
#: accelerometers.file ending .tdms (NI DAQ): the time comes from the channels' waveform properties
_TDMS_SCHEMA = {"file": "relpath", "group": "str", "upper_channel": "str", "lower_channel": "str"}


def load_yaml(path: str | Path) -> Any:
    """Parse a YAML file with the rig loader (scientific notation read as numbers, duplicate keys refused)."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise RigError(f"{path}: file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise RigError(f"{path}: cannot read ({exc})") from None
    try:
        return yaml.load(text, Loader=_RigLoader)
    except DuplicateKeyError as exc:
        raise RigError(f"{path}: {exc}") from None
    except yaml.YAMLError as exc:
        raise RigError(f"{path}: not valid YAML ({' '.join(str(exc).split())})") from None


def load_rig(path: str | Path) -> RigConfig:
    """Read and validate a rig.yaml file; raises :class:`RigError` naming file and key.

    When the recording's video is a camera file (Photron MRAW, Phantom CINE), the camera keys
    rig.yaml leaves out are taken from its header, and a clash is reported
    (:func:`vibro_io.camera_files.merge_camera_header`).
    """
    data = load_yaml(path)
    try:
        source = find_frames_source(Path(path).parent)
    except FrameError:
        camera = data.get("camera") if isinstance(data, Mapping) else None
        if isinstance(camera, Mapping) and camera.get("fps") is None:
            raise  # no frames and no rate: the missing video is the first thing to say
        source = None  # open_recording reports a missing or ambiguous video
    if source is not None and source.suffix.lower() in CAMERA_FILE_SUFFIXES:
        data = merge_camera_header(data, open_camera_file(source).header, str(path))
    rig = parse_rig(data, str(path))
    calibration_of_rig(rig)  # camera.calibration: the file read and checked now, before any work
    return rig


def _check(value: Any, kind: str, where: str) -> Any:
    """``value`` of rig.yaml key ``where`` checked against its ``kind`` (as in _SCHEMA) and converted."""
    if kind == "ball_method":
        return _check_ball_method(value, where)
    if kind in ("str", "relpath"):
        return _check_string(value, kind, where)
    if kind == "roi":
        return _check_roi(value, where)
    if kind in ("int", "posint", "odd"):
        return _check_integer(value, kind, where)
    return _check_number(value, kind, where)


def _expected(expect: str, value: Any, where: str) -> RigError:
    """The refusal of ``value`` at ``where``, saying what was ``expect``-ed."""
    return RigError(f"{where}: expected {expect}, got {value!r}")


def _check_ball_method(value: Any, where: str) -> str:
    """dic.ball_method: one of BALL_METHODS."""
    if value not in BALL_METHODS:
        raise _expected(f"one of {', '.join(BALL_METHODS)} (mesh: DIC subsets on a speckled ball; outline: a plain "
                        "ball tracked by its outline, dic.ball_roi a box around the whole ball)", value, where)
    return value


def _check_string(value: Any, kind: str, where: str) -> str:
    """A non-empty string; for ``kind`` "relpath" a file name inside the recording directory."""
    if not isinstance(value, str) or not value.strip():
        raise _expected("a non-empty string", value, where)
    problem = relative_name_problem(value) if kind == "relpath" else None
    if problem is not None:
        raise _expected(f"a file name relative to the recording directory, inside it (not {problem})", value, where)
    return value


def _check_roi(value: Any, where: str) -> Roi:
    """[x, y, w, h] in pixels: x, y >= 0, w, h > 0."""
    if not isinstance(value, (list, tuple)) or len(value) != 4:
        raise _expected("a list [x, y, w, h] of 4 integers (pixels)", value, where)
    ints = [_check(v, "int", where) for v in value]
    if ints[0] < 0 or ints[1] < 0 or ints[2] <= 0 or ints[3] <= 0:
        raise _expected("x, y >= 0 and w, h > 0 (pixels)", value, where)
    return Roi(*ints)


def _check_integer(value: Any, kind: str, where: str) -> int:
    """An integer; "posint" a positive one, "odd" a positive odd one."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or value != int(value):
        raise _expected("an integer", value, where)
    value = int(value)
    if kind in ("posint", "odd") and value <= 0:
        raise _expected("a positive integer", value, where)
    if kind == "odd" and value % 2 == 0:
        raise _expected("an odd integer (the subset has a centre pixel)", value, where)
    return value


def _check_number(value: Any, kind: str, where: str) -> float:
    """A finite number; "pos" a positive one, "poisson" a Poisson ratio in (-1, 0.5)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise _expected("a finite number", value, where)
    value = float(value)
    if kind == "pos" and value <= 0:
        raise _expected("a positive number", value, where)
    if kind == "poisson" and not -1.0 < value < 0.5:
        raise _expected("a Poisson ratio in (-1, 0.5)", value, where)
    return value


#: Optional keys per section (kind, as in _SCHEMA): absent = None.
_OPTIONAL: dict[str, dict[str, str]] = {"camera": {"start_time_unix_s": "unix_time", "mm_per_px_rel_std": "pos",
                                                   "calibration": "relpath"},
                                        "excitation": {"acceleration_mps2": "pos"},
                                        "dic": {"ball_method": "ball_method"}}
#: Keys renamed in vibro's own rig.yaml vocabulary, per section: old spelling -> new. A rig.yaml with the old
#: spelling still reads (files are written with the new one); one that gives both is refused.
_RENAMED: dict[str, dict[str, str]] = {"excitation": {"acceleration_ms2": "acceleration_mps2"}}
#: 2000-01-01T00:00:00Z: an earlier recording start is a wrong unit or a camera clock, not a date.
_EARLIEST_UNIX_S = 946684800.0


def _check_unix_time(value: Any, where: str) -> float:
    """A wall-clock time in Unix seconds: a finite number after 2000-01-01 and before now + 1 day."""
    import time

    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise RigError(f"{where}: expected a Unix time in seconds (a number, e.g. 1718000000.25), got {value!r}")
    if not _EARLIEST_UNIX_S <= value <= time.time() + 86400.0:
        raise RigError(f"{where}: expected a Unix time in seconds between 2000-01-01 and tomorrow, got {value!r} "
                       "(milliseconds or nanoseconds instead of seconds? a camera clock instead of the wall clock?)")
    return value


def _section(data: Mapping[str, Any], name: str, schema: Mapping[str, str], src: str) -> dict[str, Any]:
    if name not in data:
        unknown_top = [k for k in data if k not in _SCHEMA and k not in ("accelerometers", "setup")]
        raise RigError(f"{src}: missing required key '{name}'{_typo_hint(name, unknown_top, '')}")
    block = data[name]
    if not isinstance(block, Mapping):
        raise RigError(f"{src}: key '{name}' must be a mapping, got {block!r}")
    spelled: dict[str, str] = {}  # new key -> the old spelling this file used
    for was, now in _RENAMED.get(name, {}).items():
        if was in block:
            if now in block:
                raise RigError(f"{src}: keys '{name}.{was}' and '{name}.{now}' both given: '{was}' is the old name "
                               f"of '{now}'; keep one")
            block = {(now if k == was else k): v for k, v in block.items()}
            spelled[now] = was
    known = [*schema, *_OPTIONAL.get(name, {})]
    unknown = [k for k in block if k not in known]
    out = {}
    for key, kind in schema.items():
        if key not in block:
            raise RigError(f"{src}: missing required key '{name}.{key}'{_typo_hint(key, unknown, name + '.')}")
        out[key] = _check(block[key], kind, f"{src}: key '{name}.{key}'")
    for key, kind in _OPTIONAL.get(name, {}).items():
        if key in block and block[key] is not None:
            where = f"{src}: key '{name}.{spelled.get(key, key)}'"
            out[key] = _check_unix_time(block[key], where) if kind == "unix_time" else _check(block[key], kind, where)
    for key in unknown:
        _unknown_key(f"{name}.{key}", misspelling_of(str(key), known), name, src)
    return out


def misspelling_of(key: str, known: Iterable[str]) -> str | None:
    """The known key that ``key`` most likely misspells (difflib similarity >= 0.8: 'accelerometer' for
    'accelerometers', 'mm_per_pix' for 'mm_per_px'), or None."""
    close = difflib.get_close_matches(key, list(known), n=1, cutoff=0.8)
    return close[0] if close else None


def _typo_hint(missing: str, unknown: Iterable[Any], prefix: str) -> str:
    """`` (it has '<prefix><key>': misspelt?)`` for the first of the ``unknown`` keys that misspells the
    ``missing`` one (:func:`misspelling_of`), else ""."""
    typo = next((k for k in unknown if misspelling_of(str(k), [missing])), None)
    return "" if typo is None else f" (it has '{prefix}{typo}': misspelt?)"


#: environment variable a supervisor (``vibro graph``, the launch file) gives the nodes it starts: the digest
#: (:func:`rig_digest`) of the rig.yaml it has read already, whose warnings it has said once; a node loading that
#: same file says them at debug level only (the lab read one warning, not one per node)
RIG_CHECKED_ENV = "VIBRO_RIG_CHECKED"
_WARNED: set[tuple[str, str]] = set()   # (file, key) warned about in this process


def rig_digest(path: str | Path) -> str:
    """A short digest (16 hex of SHA-256) of the rig.yaml file's bytes; "" when it cannot be read."""
    try:
        return hashlib.sha256(Path(path).read_bytes()).hexdigest()[:16]
    except OSError:
        return ""


def rig_checked_environment(path: str | Path) -> dict[str, str]:
    """``{RIG_CHECKED_ENV: digest}`` for the nodes a supervisor starts once it has read ``path`` itself (its
    warnings said once, by the supervisor); {} when the file cannot be read."""
    digest = rig_digest(path)
    return {RIG_CHECKED_ENV: digest} if digest else {}


def _said_already(src: str, key: str) -> bool:
    """True when the warning about ``key`` of rig file ``src`` was said: in this process, or by the supervisor
    that started it (:data:`RIG_CHECKED_ENV` holds this very file's digest)."""
    if (src, key) in _WARNED:
        return True
    _WARNED.add((src, key))
    checked = os.environ.get(RIG_CHECKED_ENV, "")
    return bool(checked) and Path(src).is_file() and checked == rig_digest(src)


def _unknown_key(key: str, typo_of: str | None, section: str | None, src: str) -> None:
    """An unknown rig.yaml key: ignored with a warning (said once: :func:`_said_already`), or refused when it looks
    like a misspelt known key (the key it was meant to be would silently be missing, or take its default)."""
    if typo_of is None:
        (log.debug if _said_already(src, key) else log.warning)("%s: unknown key '%s' ignored", src, key)
        return
    meant = f"{section}.{typo_of}" if section else typo_of
    raise RigError(f"{src}: unknown key '{key}': misspelt '{meant}'? (a misspelt key is refused, not ignored: "
                   f"the value it holds would not be used)")


#: Optional keys of the accelerometers block: the unit of the samples and the sensors' sensitivity.
_ACCEL_UNIT_KEYS = ("unit", "sensitivity_mv_per_g")


def _accel_unit(value: Any, src: str) -> str | None:
    """``accelerometers.unit`` as a canonical unit (m/s^2, g, V, mV); None when absent."""
    if value is None:
        return None
    unit = canonical_unit(value) if isinstance(value, str) else None
    if unit is None:
        raise RigError(f"{src}: key 'accelerometers.unit': expected one of m/s^2, g, V, mV (the unit of the "
                       f"samples), got {value!r}")
    return unit


def _accel_sensitivity(value: Any, src: str) -> AccelSensitivity | None:
    """``accelerometers.sensitivity_mv_per_g``: one number (mV per g) or ``{upper: .., lower: ..}``."""
    key = "accelerometers.sensitivity_mv_per_g"
    if value is None:
        return None
    if not isinstance(value, Mapping):
        one = _check(value, "pos", f"{src}: key '{key}'")
        return AccelSensitivity(one, one)
    for name in value:
        if name not in ("upper", "lower"):
            raise RigError(f"{src}: key '{key}.{name}': unknown, expected 'upper' and 'lower' (mV per g of each "
                           "sensor) or one number for both")
    for name in ("upper", "lower"):
        if name not in value:
            raise RigError(f"{src}: missing required key '{key}.{name}' (mV per g)")
    return AccelSensitivity(*(_check(value[n], "pos", f"{src}: key '{key}.{n}'") for n in ("upper", "lower")))


def _check_accel_units(cfg: AccelConfig, src: str) -> None:
    """Accel.csv in volts needs the sensitivity; a sensitivity accel.csv in m/s^2 or g never uses is warned about."""
    if cfg.is_tdms:
        return  # the channels' unit strings decide, when the file is read
    if cfg.unit in VOLTAGE_UNITS and cfg.sensitivity_mv_per_g is None:
        raise RigError(f"{src}: key 'accelerometers.unit' is {cfg.unit}: add 'accelerometers.sensitivity_mv_per_g' "
                       "(the sensors' sensitivity, mV per g) to convert the samples to m/s^2")
    if cfg.unit not in VOLTAGE_UNITS and cfg.sensitivity_mv_per_g is not None:
        log.warning("%s: key 'accelerometers.sensitivity_mv_per_g' not used: the samples are in %s "
                    "(accelerometers.unit); write 'unit: V' or 'unit: mV' if %s holds voltages",
                    src, cfg.unit or "m/s^2", cfg.file)


def _parse_accel(data: Mapping[str, Any], src: str) -> AccelConfig | None:
    """The accelerometers block (None when absent): CSV columns or TDMS channels, unit and sensitivity."""
    block = data.get("accelerometers")
    if block is None:
        return None
    tdms = isinstance(block, Mapping) and isinstance(block.get("file"), str) and \
        block["file"].lower().endswith(".tdms")
    core = {k: v for k, v in block.items() if k not in _ACCEL_UNIT_KEYS} if isinstance(block, Mapping) else block
    fields = _section({"accelerometers": core}, "accelerometers", _TDMS_SCHEMA if tdms else _ACCEL_SCHEMA, src)
    extra = block if isinstance(block, Mapping) else {}
    cfg = AccelConfig(**fields, unit=_accel_unit(extra.get("unit"), src),
                      sensitivity_mv_per_g=_accel_sensitivity(extra.get("sensitivity_mv_per_g"), src))
    _check_accel_units(cfg, src)
    return cfg


def _parse_setup(data: Mapping[str, Any], src: str) -> SetupConfig:
    """The optional ``setup`` block (how the rig is mounted): ``axis_tilt_deg`` in [0, 90] degrees from vertical
    (absent: 0, vertical). Refused naming the key: not a mapping, not a number, outside [0, 90]."""
    block = data.get("setup")
    if block is None:
        return SetupConfig()
    if not isinstance(block, Mapping):
        raise RigError(f"{src}: key 'setup' must be a mapping (e.g. 'setup: {{axis_tilt_deg: 45}}'), got {block!r}")
    known = [f.name for f in SetupConfig.__dataclass_fields__.values()]
    for key in block:
        if key not in known:
            _unknown_key(f"setup.{key}", misspelling_of(str(key), known), "setup", src)
    tilt = block.get("axis_tilt_deg")
    if tilt is None:
        return SetupConfig()
    where = f"{src}: key 'setup.axis_tilt_deg'"
    lo, hi = AXIS_TILT_RANGE_DEG
    if isinstance(tilt, bool) or not isinstance(tilt, (int, float)) or not math.isfinite(tilt):
        raise RigError(f"{where}: expected the motion axis' angle from vertical in degrees, a number in [{lo:g}, "
                       f"{hi:g}] (0 vertical, 90 horizontal), got {tilt!r}")
    if not lo <= float(tilt) <= hi:
        raise RigError(f"{where}: expected the motion axis' angle from vertical in [{lo:g}, {hi:g}] degrees (0 "
                       f"vertical, 45 tilted, 90 horizontal: the axis from the lower plate to the upper one), "
                       f"got {tilt!r}")
    return SetupConfig(axis_tilt_deg=float(tilt))


def parse_rig(data: Any, source: str = "rig.yaml") -> RigConfig:
    """Validate a rig mapping (as parsed from YAML) into a :class:`RigConfig`."""
    if not isinstance(data, Mapping):
        raise RigError(f"{source}: expected a mapping at the top level, got {type(data).__name__}")
    sections = {name: _section(data, name, schema, source) for name, schema in _SCHEMA.items()}
    accel = _parse_accel(data, source)
    setup = _parse_setup(data, source)
    for key in data:
        if key not in _SCHEMA and key not in ("accelerometers", "setup"):
            _unknown_key(str(key), misspelling_of(str(key), [*_SCHEMA, "accelerometers", "setup"]), None, source)
    rig = RigConfig(
        camera=CameraConfig(**sections["camera"]),
        ball=BallConfig(**sections["ball"]),
        structure=StructureConfig(**sections["structure"]),
        excitation=ExcitationConfig(**sections["excitation"]),
        dic=DicConfig(**sections["dic"], ball_method_named="ball_method" in sections["dic"]),
        accelerometers=accel,
        path=source,
        setup=setup,
    )
    if rig.structure.gap_mm <= rig.ball.diameter_mm:
        raise RigError(
            f"{source}: key 'structure.gap_mm' ({rig.structure.gap_mm}) must exceed "
            f"'ball.diameter_mm' ({rig.ball.diameter_mm}): the ball has no room to move"
        )
    return rig


def check_rois_in_image(rig: RigConfig, height_px: int, width_px: int) -> None:
    """Raise :class:`RigError` if a ROI leaves the image or cannot hold one subset.

    Convention: mesh points are placed so that every subset lies inside its ROI.
    """
    for name in ("ball_roi", "structure_roi"):
        roi: Roi = getattr(rig.dic, name)
        if roi.x + roi.w > width_px or roi.y + roi.h > height_px:
            raise RigError(
                f"{rig.path}: key 'dic.{name}' {roi.as_list()} (x, y, w, h in pixels) "
                f"goes outside the {width_px}x{height_px} px image"
            )
        if name == "ball_roi" and rig.dic.ball_method == "outline":
            continue  # a box around the whole ball, not a mesh of subsets
        if roi.w < rig.dic.subset_px or roi.h < rig.dic.subset_px:
            raise RigError(
                f"{rig.path}: key 'dic.{name}' {roi.as_list()} is smaller than one "
                f"{rig.dic.subset_px} px subset (dic.subset_px)"
            )


def write_rig(rig: RigConfig, path: str | Path) -> None:
    """Write ``rig`` as YAML to ``path``."""
    Path(path).write_text(yaml.safe_dump(rig.to_dict(), sort_keys=False), encoding="utf-8")
