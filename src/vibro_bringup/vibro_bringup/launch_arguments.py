"""The launch file's arguments (``ros2 launch vibro_bringup vibro.launch.py name:=value``), read and checked.

Plain functions (no launch import) so that what a lab types is checked the same here and under ``ros2 launch``.
Each returns the value the graph uses, or raises :class:`LaunchArgumentError` with one line naming the argument,
what it got and what it takes (launch prints it and exits 1 before any node starts).

ros2launch refuses an empty value (``bag:=`` is "malformed"), and a shell passes ``bag:=""`` as ``bag:=``: the
way to say "none" is a word, ``bag:=none`` (``record:=false`` also switches the recorder off).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from .isolation import namespace_argument

#: values of ``bag`` that mean: record no bag (quotes a shell or a launch file left in the value count as empty)
NO_BAG = ("", "none", "false", "off", "no", '""', "''")
_TRUE = ("true", "1", "yes", "on")
_FALSE = ("false", "0", "no", "off")


class LaunchArgumentError(ValueError):
    """A launch argument with a value the graph cannot use; the message names it."""


def flag(name: str, text: str) -> bool:
    """``true``/``false`` (also 1/0, yes/no, on/off, any case) of argument ``name``."""
    value = text.strip().lower()
    if value in _TRUE:
        return True
    if value in _FALSE:
        return False
    raise LaunchArgumentError(f"{name}:={text}: expected true or false")


def bag_directory(text: str, record: str = "true") -> str | None:
    """The bag directory to record to, or None (no recorder) for ``bag:=none`` (or empty) or ``record:=false``."""
    if not flag("record", record) or text.strip().lower() in NO_BAG:
        return None
    path = Path(text.strip()).expanduser()
    if path.exists() and (not path.is_dir() or any(path.iterdir())):
        raise LaunchArgumentError(f"bag:={text}: exists and is not an empty folder (a bag is never recorded over "
                                  "another; choose a new path, or bag:=none to record nothing)")
    return str(path)


def namespace(text: str) -> str | None:
    """The ROS namespace to start every node in (``namespace:=lab1`` or ``/lab1``), None for empty or ``/``."""
    if text.strip() in ("", "/"):
        return None
    try:
        return namespace_argument(text.strip())
    except argparse.ArgumentTypeError as exc:
        raise LaunchArgumentError(f"namespace:={text}: {exc}") from None


def time_origin_ns(text: str) -> int | None:
    """``time_origin_unix_ns``: wall time (ns since the Unix epoch) of data time 0 on the stamps, None for empty
    (the recording's ``camera.start_time_unix_s``, else the launch's start)."""
    value = text.strip()
    if not value:
        return None
    try:
        ns = int(value)
    except ValueError:
        raise LaunchArgumentError(f"time_origin_unix_ns:={text}: expected an integer number of nanoseconds since "
                                  "the Unix epoch (e.g. 1764000000000000000)") from None
    if ns <= 10**18:  # before 2001-09-09: seconds or milliseconds given for nanoseconds, or a data time
        raise LaunchArgumentError(f"time_origin_unix_ns:={text}: not a wall time in nanoseconds (before 2001); "
                                  "seconds or milliseconds given?")
    return ns


def _existing_file(name: str, text: str) -> Path | None:
    """Launch argument ``name``: an existing file (resolved), None for empty."""
    value = text.strip()
    if not value:
        return None
    path = Path(value).expanduser()
    if not path.is_file():
        raise LaunchArgumentError(f"{name}:={text}: no such file")
    return path.resolve()


def reference_image(text: str) -> Path | None:
    """``reference_image``: an existing image file (dic_tracker's DIC reference: frame 0), None for empty."""
    path = _existing_file("reference_image", text)
    if path is None:
        return None
    import cv2

    if cv2.imread(str(path), cv2.IMREAD_UNCHANGED) is None:
        raise LaunchArgumentError(f"reference_image:={text}: not an image OpenCV can read")
    return path


def params_file(text: str) -> Path | None:
    """``params_file``: a parameters YAML replacing the installed defaults (config/vibro.yaml), None for empty."""
    return _existing_file("params_file", text)
