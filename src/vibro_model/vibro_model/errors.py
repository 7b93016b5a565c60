"""Exceptions for bad input: each names the file (and key, line or frame) at fault."""

from __future__ import annotations


class RecordingError(Exception):
    """Bad input from outside (a file, a parameter, a message).

    The CLI prints ``str(error)`` without a traceback, so the message must say
    what is wrong and where.
    """


class RigError(RecordingError):
    """A rig.yaml that is missing, unreadable or inconsistent."""


class FrameError(RecordingError):
    """A frame file or video that cannot be read, or frames that do not match."""


class AccelError(RecordingError):
    """An accelerometer CSV that cannot be read or is inconsistent."""
