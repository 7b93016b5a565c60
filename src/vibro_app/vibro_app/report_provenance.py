r"""Where an analysis came from: the command line, the code, every input file's SHA-256 and rig.yaml as used.

:func:`provenance_section` builds results.json's ``provenance`` section (``vibro analyze`` writes it; the
contract allows new top-level sections, docs/recording-format.md), :func:`reproduce_html` prints it as the
report's *Reproduce* block. Plain module (hashlib, subprocess; no matplotlib).

Digests: a file's SHA-256 is of its bytes, read in 1 MiB chunks (a 1 GB video is never held in memory). A folder
of frames gets one digest, of its manifest: one ``sha256sum`` line per file (``<hex>  <path>``, paths relative
to the folder with ``/``, sorted by their UTF-8 bytes), so a reader checks it with
``(cd frames && find . -type f -printf '%P\n' | LC_ALL=C sort | xargs -d '\n' sha256sum) | sha256sum``.
The time the hashing took is recorded beside (``hash_seconds``, ``hash_bytes``).
"""

from __future__ import annotations

import hashlib
import html
import os
import shlex
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, Mapping, Sequence

import yaml

from vibro_app.version import package_version
from vibro_io.frames_source import find_frames_source
from vibro_io.rig import load_rig

#: bytes read at a time when hashing
HASH_CHUNK = 1 << 20
#: seconds the git query may take before the commit is "unknown"
GIT_TIMEOUT_S = 5.0
#: the command name a recorded command line starts with
COMMAND = "vibro"


def sha256_file(path: str | Path, chunk: int = HASH_CHUNK) -> str:
    """The SHA-256 (hex) of a file's bytes, read in chunks of ``chunk`` bytes."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(chunk), b""):
            h.update(block)
    return h.hexdigest()


def folder_files(folder: str | Path) -> list[tuple[str, Path]]:
    """(relative path with '/', path) of every file under ``folder`` (symlinks to files followed), sorted by the
    relative path's UTF-8 bytes (``LC_ALL=C sort``)."""
    folder = Path(folder)
    out = []
    for root, _dirs, files in os.walk(folder):
        for name in files:
            p = Path(root) / name
            if p.is_file():
                out.append((p.relative_to(folder).as_posix(), p))
    return sorted(out, key=lambda item: item[0].encode("utf-8", "surrogateescape"))


def folder_digest(folder: str | Path) -> dict[str, Any]:
    """``{"sha256", "files", "bytes"}`` of a folder: the SHA-256 of its ``sha256sum`` manifest (module doc)."""
    manifest = hashlib.sha256()
    n_bytes = 0
    files = folder_files(folder)
    for rel, p in files:
        manifest.update(f"{sha256_file(p)}  {rel}\n".encode("utf-8", "surrogateescape"))
        n_bytes += p.stat().st_size
    return {"sha256": manifest.hexdigest(), "files": len(files), "bytes": n_bytes}


def _camera_data_files(source: Path) -> list[Path]:
    """A Photron header's raw data beside it (same name, ``.mraw`` in any case); nothing for other sources."""
    if source.suffix.lower() not in (".cih", ".cihx"):
        return []
    return sorted(p for p in source.parent.iterdir()
                  if p.is_file() and p.stem == source.stem and p.suffix.lower() == ".mraw")


def input_files(recording_dir: str | Path, track_csv: str | Path | None, rig=None) -> list[tuple[str, Path]]:
    """(role, path) of every file or folder the analysis read: the frames (a folder, or a video / camera file and
    its raw data) unless a track replaced them, rig.yaml (``rig``'s own file when it names one, else the
    recording's), the accelerometer file rig.yaml names, the track. ``rig``: the RigConfig the analysis used
    (None: read from the recording's rig.yaml)."""
    from vibro_io.recording import accel_file

    rec = Path(recording_dir)
    out: list[tuple[str, Path]] = []
    if track_csv is None:
        source = find_frames_source(rec)
        out.append(("frames", source))
        out += [("camera raw data", p) for p in _camera_data_files(source)]
    rig_path = Path(rig.path) if rig is not None and getattr(rig, "path", None) else rec / "rig.yaml"
    out.append(("rig.yaml", rig_path))
    accel = accel_file(rec, rig if rig is not None else load_rig(rig_path))
    if accel is not None:
        out.append(("accelerometers", accel))
    if track_csv is not None:
        out.append(("DIC track", Path(track_csv)))
    return out


def hash_inputs(entries: Sequence[tuple[str, Path]]) -> tuple[list[dict[str, Any]], float, int]:
    """(one dict per input: role, path, kind, sha256, bytes and for a folder its file count; seconds the hashing
    took; bytes hashed)."""
    t0 = time.perf_counter()
    rows, total = [], 0
    for role, path in entries:
        if not path.exists():  # an input given in memory (a RigConfig built by a caller): nothing on disk to hash
            rows.append({"role": role, "path": str(path), "kind": "not a file", "sha256": None, "bytes": 0})
        elif path.is_dir():
            d = folder_digest(path)
            rows.append({"role": role, "path": str(path), "kind": "folder", "sha256": d["sha256"], "bytes": d["bytes"],
                         "files": d["files"]})
        else:
            d = {"bytes": path.stat().st_size}
            rows.append({"role": role, "path": str(path), "kind": "file", "sha256": sha256_file(path), **d})
        total += rows[-1]["bytes"]
    return rows, time.perf_counter() - t0, total


def git_commit(where: str | Path | None = None, timeout_s: float = GIT_TIMEOUT_S) -> str:
    """``git rev-parse HEAD`` of the source tree ``where`` (default: this package's folder), or "unknown" when it
    is not a git checkout, git is missing or slow; never raises. Read-only: no index refresh, no lock."""
    here = Path(where) if where is not None else Path(__file__).resolve().parent
    try:
        done = subprocess.run(["git", "-C", str(here), "rev-parse", "HEAD"], capture_output=True, text=True,
                              timeout=timeout_s, check=False)
    except (OSError, subprocess.SubprocessError, ValueError):
        return "unknown"
    commit = done.stdout.strip()
    return commit if done.returncode == 0 and len(commit) >= 40 else "unknown"


def provenance_section(recording_dir: str | Path, track_csv: str | Path | None, *,
                       command: Sequence[str] | None, settings: Mapping[str, Any], rig=None) -> dict[str, Any]:
    """results.json's ``provenance``: the command line (None when the analysis was not run by ``vibro analyze``,
    e.g. a campaign or a Python call), the working folder, vibro's version and commit, the Python version, every
    input with its SHA-256 (:func:`hash_inputs`), how long the hashing took, rig.yaml's text as read, and the
    ``settings`` the analysis ran with (the DIC's and the identification's options and thresholds); ``rig``: the
    RigConfig used (its file is the one hashed; one built in memory is written out as YAML)."""
    entries = input_files(recording_dir, track_csv, rig)
    rig_path = next(p for role, p in entries if role == "rig.yaml")
    rig_bytes = rig_path.read_bytes() if rig_path.is_file() else yaml.safe_dump(rig.to_dict()).encode()
    inputs, seconds, n_bytes = hash_inputs(entries)
    return {"command": None if command is None else [str(a) for a in command], "cwd": os.getcwd(),
            "vibro_version": package_version(), "git_commit": git_commit(),
            "python": sys.version.split()[0], "inputs": inputs, "hash_seconds": seconds, "hash_bytes": n_bytes,
            "rig_yaml": rig_bytes.decode("utf-8", "replace"), "settings": dict(settings)}


def command_text(prov: Mapping[str, Any]) -> str | None:
    """The recorded command as one shell line run from the folder it was run in (``cd <cwd> && vibro ...``);
    None when none was recorded."""
    argv = prov.get("command")
    if not argv:
        return None
    line = " ".join(shlex.quote(str(a)) for a in argv)
    cwd = prov.get("cwd")
    return f"cd {shlex.quote(str(cwd))} && {line}" if cwd else line


def _size(n: int) -> str:
    for unit, k in (("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if n >= k:
            return f"{n / k:.3g} {unit}"
    return f"{n} B"


def hashing_text(prov: Mapping[str, Any]) -> str:
    """How long the input digests took, and a note when they cost more than a second per GB."""
    seconds, n = prov.get("hash_seconds"), prov.get("hash_bytes")
    if seconds is None or not n:
        return ""
    per_gb = seconds / (n / 1e9)
    rate = f"{per_gb:.2g} s per GB" + (", more than 1 s per GB" if per_gb > 1.0 else "")
    return f"Hashing the inputs ({_size(int(n))}) took {seconds:.3g} s ({rate})."


def reproduce_html(prov: Mapping[str, Any] | None) -> str:
    """The report's *Reproduce* block: the command line, vibro's version and commit, each input's SHA-256 and
    rig.yaml verbatim (escaped); user text (paths, the command, rig.yaml) sits in elements marked
    ``data-verbatim``."""
    e = html.escape
    if not prov:
        return ('<h2 id="reproduce">Reproduce</h2><p>These results record no provenance (written before vibro '
                "recorded it, or not by <code>vibro analyze</code>).</p>")
    line = command_text(prov)
    cmd = (f'<pre data-verbatim="command" id="command">{e(line)}</pre>' if line else
           "<p>Not run from the vibro command line (a campaign or a Python call): no command line recorded.</p>")
    rows = "".join(
        f'<tr><td>{e(str(i.get("role", "")))}</td><td><code data-verbatim="path">{e(str(i.get("path", "")))}</code>'
        f'</td><td>{e(str(i.get("kind", "")))}' + (f', {i["files"]} files' if i.get("kind") == "folder" else "")
        + f'</td><td>{_size(int(i.get("bytes") or 0))}</td><td><code class="sha256">{e(str(i.get("sha256", "")))}'
          "</code></td></tr>" for i in prov.get("inputs") or [])
    rig = prov.get("rig_yaml")
    return ('<h2 id="reproduce">Reproduce</h2><p>The command that made these results (run it with another '
            "output folder to compare):</p>" + cmd
            + f"<p>vibro {e(str(prov.get('vibro_version', 'unknown')))}, git commit "
              f"<code>{e(str(prov.get('git_commit') or 'unknown'))}</code>, Python "
              f"{e(str(prov.get('python', '?')))}.</p>"
            + "<table id=\"inputs\"><tr><th>input</th><th>path</th><th>kind</th><th>size</th><th>SHA-256</th></tr>"
            + rows + "</table><p>A file's SHA-256 is of its bytes; a folder's is of its manifest, one "
              "<code>sha256sum</code> line per file sorted by path: "
              "<code>(cd FOLDER &amp;&amp; find . -type f -printf '%P\\n' | LC_ALL=C sort | xargs -d '\\n' sha256sum)"
              " | sha256sum</code>. " + e(hashing_text(prov)) + "</p>"
            + ("<p>rig.yaml as used:</p>" + f'<pre data-verbatim="rig.yaml" id="rig-yaml">{e(rig)}</pre>'
               if rig is not None else ""))
