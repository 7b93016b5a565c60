"""The runs of a campaign: recordings found under a folder, or listed in a text file; their names.

A recording is a folder holding ``rig.yaml`` (docs/recording-format.md). Under a folder, every folder
holding rig.yaml is a run (searched recursively; not inside a recording); its name is its path relative
to that folder (the folder itself, when it is a recording: its own name). A list file names one recording
folder per line (relative to the list file's folder, or absolute; blank lines and ``#`` comments
skipped); a listed folder that is missing is still a run, reported failed. Each run's outputs go to
``OUT/<name>/``.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

from vibro_model.errors import RecordingError

RIG_YAML = "rig.yaml"


@dataclass(frozen=True)
class RunSpec:
    """One recording of the campaign: ``name`` (posix, relative; also its output folder) and ``path``."""

    name: str
    path: Path


def find_runs(source: str | Path, exclude: str | Path | None = None) -> list[RunSpec]:
    """The runs of ``source`` (a folder or a list file), sorted by name; ``exclude``: a folder not searched
    (the campaign's own output). :class:`RecordingError` when there is none, or two runs share a name."""
    source = Path(source)
    if source.is_dir():
        runs = _runs_in_folder(source, Path(exclude).resolve() if exclude is not None else None)
        if not runs:
            raise RecordingError(f"{source}: no recording in this folder (no {RIG_YAML} in it or below it)")
    elif source.is_file():
        runs = _runs_in_list(source)
        if not runs:
            raise RecordingError(f"{source}: the list names no recording (one folder per line)")
    else:
        raise RecordingError(f"{source}: no such folder or list file")
    return sorted(runs, key=lambda r: r.name)


def _runs_in_folder(root: Path, exclude: Path | None) -> list[RunSpec]:
    if (root / RIG_YAML).is_file():
        return [RunSpec(root.resolve().name, root)]
    runs = []
    for folder, subdirs, files in os.walk(root, followlinks=False):
        here = Path(folder)
        if exclude is not None and here.resolve() == exclude:
            subdirs[:] = []
            continue
        if RIG_YAML in files and here != root:
            runs.append(RunSpec(here.relative_to(root).as_posix(), here))
            subdirs[:] = []  # nothing else in a recording is read
        subdirs.sort()
    return runs


def _runs_in_list(list_file: Path) -> list[RunSpec]:
    base = list_file.parent
    try:
        lines = list_file.read_text(encoding="utf-8").splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise RecordingError(f"{list_file}: cannot read the list ({exc})") from None
    runs: dict[str, tuple[int, RunSpec]] = {}
    for line_no, line in enumerate(lines, start=1):
        entry = line.split("#", 1)[0].strip()
        if not entry:
            continue
        path = Path(entry) if Path(entry).is_absolute() else base / entry
        try:
            name = path.resolve().relative_to(base.resolve()).as_posix()
        except ValueError:
            name = path.resolve().name
        if name in ("", ".", "..") or name.startswith("../"):
            raise RecordingError(f"{list_file}: line {line_no}: {entry!r} is not a recording folder")
        if name in runs:
            raise RecordingError(f"{list_file}: line {line_no}: run name {name!r} already given on line "
                                 f"{runs[name][0]} (each run's outputs go to OUT/<name>)")
        runs[name] = (line_no, RunSpec(name, path))
    return [spec for _, spec in runs.values()]
