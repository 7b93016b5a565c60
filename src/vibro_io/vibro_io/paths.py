"""Files of a recording resolve inside its directory, never outside.

A recording names its files relative to its own directory (rig.yaml's
``accelerometers.file``, ``frames/``, ``video.*``). An absolute path, a ``..`` step or a
symlink that leads out of the directory is refused before the file is opened, so that
nothing outside the recording is ever read or echoed in a message.
"""

from __future__ import annotations

from pathlib import Path, PurePath

from vibro_model.errors import RecordingError


def relative_name_problem(name: str) -> str | None:
    """Why ``name`` cannot name a file inside a recording (absolute, ``..``), or None if it can."""
    pure = PurePath(name)
    if pure.is_absolute() or pure.drive:
        return "an absolute path"
    if ".." in pure.parts:
        return "a path with '..'"
    return None


def inside_recording(recording: str | Path, relative: str | Path, what: str) -> Path:
    """``recording / relative`` if it resolves inside the ``recording`` directory; else :class:`RecordingError`.

    ``relative`` is a name relative to the recording directory. ``what`` says where the name
    comes from (e.g. ``"rig.yaml: key 'accelerometers.file'"``) and opens the message.
    Symlinks are followed: one that leads outside the recording is refused like an absolute path.
    """
    recording = Path(recording)
    problem = relative_name_problem(str(relative))
    if problem is not None:
        raise RecordingError(
            f"{what} names {relative}, {problem}: files of a recording are named relative to its "
            f"directory {recording} and must lie inside it")
    target = (recording / relative).resolve()
    if not target.is_relative_to(recording.resolve()):
        raise RecordingError(
            f"{what} names {relative}, which leads outside the recording directory {recording} "
            f"(a symlink to {target}); copy the file into the recording instead")
    return recording / relative
