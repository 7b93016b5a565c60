"""Output folders and files of the vibro commands: never mix two runs, never leave half a file.

Two rules for every file a command writes for the user (results.json, dic.csv, CSV tables,
figures, report.html, recordings, bags):

1. An output folder must be new or empty (this run's own input files in it do not count).
   ``--overwrite`` replaces the outputs of an earlier run of the same command: it removes
   exactly the entries the command owns (``owned``: glob patterns relative to the folder, e.g.
   ``"results.json"``, ``"bag/*.mcap"``; a sub-folder is owned when everything in it is) and
   refuses when anything else is there, so an unrelated file is never deleted and never left
   beside fresh results.
2. Each file is written to a temporary file in the same folder, fsynced, then renamed over
   the target (``os.replace``, atomic on POSIX): a crash leaves the previous file or the new
   one, never half of one. A killed process may leave a temporary ``.NAME.xxxxxxxx.vibro-tmp*``
   file behind; it never has the target's name, and ``--overwrite`` removes it with the rest.

Errors are :class:`OutputError` (a :class:`~vibro_model.errors.RecordingError`): the CLI prints
them as one line naming the path and the reason, exit code 2.
"""

from __future__ import annotations

import os
import re
import shutil
import tempfile
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from fnmatch import fnmatchcase
from pathlib import Path
from typing import IO

from vibro_model.errors import RecordingError

TEMP_MARK = ".vibro-tmp"
_TEMP_NAME = re.compile(r"^\.(?P<name>.+)\.[a-z0-9_]{8}" + re.escape(TEMP_MARK) + r"(\.[^.]*)?$")
_UMASK = os.umask(0o022)
os.umask(_UMASK)
_FILE_MODE = 0o666 & ~_UMASK


class OutputError(RecordingError):
    """An output path that cannot be used: exists, is not a folder, is not writable, holds other files."""


def _reason(exc: OSError) -> str:
    return exc.strerror or str(exc)


def _listing(entries: list[Path], limit: int = 5) -> str:
    names = [e.name + ("/" if e.is_dir() and not e.is_symlink() else "") for e in entries[:limit]]
    return ", ".join(names) + (f" and {len(entries) - limit} more" if len(entries) > limit else "")


def _file_owned(rel: str, owned: tuple[str, ...]) -> bool:
    """Whether the file at ``rel`` (posix path relative to the output folder) is one of ``owned``,
    or a temporary file left by an interrupted atomic write of one."""
    head, _, name = rel.rpartition("/")
    match = _TEMP_NAME.match(name)
    if match:
        rel = f"{head}/{match['name']}" if head else match["name"]
    depth = rel.count("/")
    return any(p.count("/") == depth and fnmatchcase(rel, p) for p in owned)


def _entry_owned(folder: Path, entry: Path, owned: tuple[str, ...]) -> bool:
    """Whether ``entry`` (inside ``folder``) is an output of the command owning ``owned``: a file or
    link matching a pattern, or a real folder named in a pattern whose every entry is owned."""
    rel = entry.relative_to(folder).as_posix()
    if entry.is_symlink() or not entry.is_dir():
        return _file_owned(rel, owned)
    if not any(p.startswith(rel + "/") for p in owned):
        return False
    return all(_entry_owned(folder, child, owned) for child in entry.iterdir())


def _holds(entry: Path, inputs: list[Path]) -> bool:
    """Whether ``entry`` is, or contains, one of the (resolved) ``inputs``."""
    here = entry.resolve()
    return any(p == here or here in p.parents for p in inputs)


def _remove(entry: Path) -> None:
    try:
        if entry.is_symlink() or not entry.is_dir():
            entry.unlink()
        else:
            shutil.rmtree(entry)
    except OSError as exc:
        raise OutputError(f"{entry}: cannot remove the earlier output ({_reason(exc)})") from exc


def _check_writable(folder: Path, label: Path) -> None:
    """Create and remove a probe file in ``folder``; OutputError naming ``label`` if that fails."""
    try:
        fd, probe = tempfile.mkstemp(dir=folder, prefix=".write-probe.", suffix=TEMP_MARK)
    except OSError as exc:
        raise OutputError(f"{label}: cannot write in {folder} ({_reason(exc)})") from exc
    os.close(fd)
    os.unlink(probe)


def _make_folder(folder: Path, label: Path) -> None:
    if folder.exists() and not folder.is_dir():
        raise OutputError(f"{label}: {folder} exists and is not a folder" if folder != label
                          else f"{label}: exists and is not a folder")
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        where = "" if folder == label else f" {folder}"
        raise OutputError(f"{label}: cannot create the folder{where} ({_reason(exc)})") from exc


def prepare_output_dir(path: str | Path, *, overwrite: bool, owned: Iterable[str], command: str,
                       inputs: Iterable[str | Path] = ()) -> Path:
    """Make ``path`` a usable, empty output folder for ``vibro <command>`` and return it.

    Created when missing. Entries that are (or hold) one of this run's ``inputs`` are kept and do
    not count. Anything else there: refused unless ``overwrite``; with ``overwrite`` every such entry
    must match ``owned`` (glob patterns relative to ``path``; see the module docstring) and is then
    removed, otherwise refused and nothing is removed. Raises :class:`OutputError`.
    """
    path = Path(path)
    owned = tuple(owned)
    if (path.exists() or path.is_symlink()) and not path.is_dir():
        raise OutputError(f"{path}: exists and is not a folder")
    if not path.exists():
        _make_folder(path, path)
    try:
        entries = sorted(path.iterdir())
    except OSError as exc:
        raise OutputError(f"{path}: cannot list the output folder ({_reason(exc)})") from exc
    resolved_inputs = [Path(p).resolve() for p in inputs]
    stale = [e for e in entries if not _holds(e, resolved_inputs)]
    if stale:
        if not overwrite:
            raise OutputError(f"{path}: output folder is not empty ({_listing(stale)}); give --overwrite to "
                              f"replace the outputs of an earlier 'vibro {command}', or choose a new folder")
        foreign = [e for e in stale if not _entry_owned(path, e, owned)]
        if foreign:
            raise OutputError(f"{path}: not replaced: {_listing(foreign)} {'is' if len(foreign) == 1 else 'are'} "
                              f"not output of 'vibro {command}' (--overwrite only removes that command's own "
                              "files); move them away or choose a new folder")
        for entry in stale:
            _remove(entry)
    _check_writable(path, path)
    return path


def prepare_output_entries(folder: str | Path, names: Iterable[str], *, overwrite: bool, owned: Iterable[str],
                           command: str) -> Path:
    """Make the entries ``names`` of ``folder`` free for ``vibro <command>`` to create (e.g. a bag and its
    log folder), leaving the rest of ``folder`` alone; returns ``folder`` (created when missing).

    An existing entry is refused unless ``overwrite``; with ``overwrite`` it must match ``owned`` (patterns
    relative to ``folder``) and is removed, otherwise refused. Raises :class:`OutputError`.
    """
    folder = Path(folder)
    owned = tuple(owned)
    targets = [folder / n for n in names]
    label = targets[0] if targets else folder
    _make_folder(folder, label)
    existing = [t for t in targets if t.exists() or t.is_symlink()]
    for entry in existing:
        if not overwrite:
            raise OutputError(f"{entry}: already exists; give --overwrite to replace it, or choose a new name")
        if not _entry_owned(folder, entry, owned):
            raise OutputError(f"{entry}: not replaced: it does not look like an output of 'vibro {command}' "
                              "(--overwrite only removes that command's own files); choose a new name")
    for entry in existing:
        _remove(entry)
    _check_writable(folder, label)
    return folder


def prepare_output_file(path: str | Path, *, overwrite: bool) -> Path:
    """Check that the single output file ``path`` may be written: not a folder, not existing unless
    ``overwrite`` (it is then replaced atomically when written), its folder creatable and writable."""
    path = Path(path)
    if path.is_dir():
        raise OutputError(f"{path}: is a folder; give a file name")
    if (path.exists() or path.is_symlink()) and not overwrite:
        raise OutputError(f"{path}: already exists; give --overwrite to replace it, or choose a new name")
    _make_folder(path.parent, path)
    _check_writable(path.parent, path)
    return path


def _fsync_path(path: Path, flags: int = os.O_RDONLY) -> None:
    fd = os.open(path, flags)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


@contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path beside ``path`` for a writer that takes a file name (matplotlib's
    ``savefig``, ``cv2.imwrite``, ``np.savetxt``); it ends with ``path``'s suffix, so writers that
    infer the format from the name work. On normal exit the file is fsynced and renamed to ``path``
    (atomic); if the block raises, it is removed and ``path`` is left as it was."""
    path = Path(path)
    try:
        fd, name = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=TEMP_MARK + path.suffix)
    except OSError as exc:
        raise OutputError(f"{path}: cannot write ({_reason(exc)})") from exc
    os.close(fd)
    tmp = Path(name)
    try:
        yield tmp
        _fsync_path(tmp)
        os.chmod(tmp, _FILE_MODE)
        os.replace(tmp, path)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        raise OutputError(f"{path}: cannot write ({_reason(exc)})") from exc
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    try:
        _fsync_path(path.parent, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))  # the rename itself
    except OSError:
        pass  # some file systems cannot fsync a folder; the file's data is already on disk


@contextmanager
def atomic_open(path: str | Path, mode: str = "w", *, encoding: str = "utf-8", newline: str | None = None
                ) -> Iterator[IO]:
    """Open a temporary file beside ``path`` for writing (``mode`` "w" or "wb"); on normal exit it
    replaces ``path`` atomically, if the block raises ``path`` is untouched and no file is left."""
    if "w" not in mode:
        raise ValueError(f"atomic_open writes a new file: mode {mode!r} must contain 'w'")
    kwargs = {} if "b" in mode else {"encoding": encoding, "newline": newline}
    with atomic_path(path) as tmp, open(tmp, mode, **kwargs) as handle:
        yield handle


def atomic_write_text(path: str | Path, text: str, encoding: str = "utf-8") -> Path:
    """Write ``text`` to ``path`` atomically (see :func:`atomic_path`); returns ``path``."""
    with atomic_open(path, "w", encoding=encoding) as handle:
        handle.write(text)
    return Path(path)


def atomic_write_bytes(path: str | Path, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically (see :func:`atomic_path`); returns ``path``."""
    with atomic_open(path, "wb") as handle:
        handle.write(data)
    return Path(path)
