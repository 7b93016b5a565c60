"""What a run's outputs were made from, so that a campaign resumes without redoing finished runs.

The fingerprint of a run is the SHA-256 of: rig.yaml's content; the relative path, size (bytes) and
modification time (ns) of every other file in the recording folder (frames, video, accelerometers);
vibro's code version (:func:`code_version`); and the analysis options. After a run's outputs are complete
it is written to ``OUT/<run>/campaign-run.json`` (atomically, last); a run whose stored fingerprint equals
the current one is not redone. A run whose recording was refused as bad input (a RecordingError: its
reason is stored with the fingerprint) is not retried either while nothing changed; a run that failed
otherwise (an internal error, a worker that died) stores nothing and is retried. Any change (a file
touched, rig.yaml edited, vibro's code changed, other options) redoes the run.
"""

from __future__ import annotations

import hashlib
import importlib.util
import json
import os
from functools import lru_cache
from pathlib import Path

from vibro_io.outputs import atomic_write_text

FINGERPRINT_JSON = "campaign-run.json"
FINGERPRINT_SCHEMA = "vibro.campaign-run/1"
#: the packages whose code makes a run's results (their .py files make the code version)
CODE_PACKAGES = ("vibro_model", "vibro_io", "vibro_dic", "vibro_fit", "vibro_sim", "vibro_discrepancy", "vibro_app")


@lru_cache(maxsize=1)
def code_version() -> str:
    """Vibro's version as ``<release>+src.<hash>``: the release number of vibro_app and the SHA-256
    (16 hex) of every .py file of :data:`CODE_PACKAGES` (path and content), so that any code change counts."""
    digest = hashlib.sha256()
    for package in CODE_PACKAGES:
        spec = importlib.util.find_spec(package)
        roots = list(spec.submodule_search_locations or []) if spec is not None else []
        for root in roots:
            for path in sorted(Path(root).rglob("*.py")):
                digest.update(f"{package}/{path.relative_to(root).as_posix()}\0".encode())
                digest.update(path.read_bytes())
    try:
        from importlib.metadata import PackageNotFoundError, version

        release = version("vibro_app")
    except PackageNotFoundError:
        release = "0.1.0"  # a development install (source folders on sys.path), as setup.py says
    return f"{release}+src.{digest.hexdigest()[:16]}"


def input_fingerprint(recording: str | Path, options: dict, version: str | None = None, *,
                      sizes: dict | None = None) -> str:
    """The fingerprint (hex) of ``recording`` analysed with ``options`` by vibro ``version`` (module doc).
    A recording folder that is missing has a fingerprint too (it is never stored: that run fails).
    ``sizes``, when given, receives ``bytes``: the recording's files' total size (the campaign's estimate of
    a run's cost, from the same walk)."""
    recording = Path(recording)
    total = 0
    digest = hashlib.sha256()
    digest.update(json.dumps({"version": version or code_version(), "options": options}, sort_keys=True).encode())
    rig = recording / "rig.yaml"
    try:
        digest.update(b"rig.yaml\0" + rig.read_bytes())
    except OSError:
        digest.update(b"rig.yaml\0<unreadable>")
    for folder, subdirs, files in os.walk(recording):
        subdirs.sort()
        for name in sorted(files):
            path = Path(folder) / name
            if path == rig:
                continue
            try:
                st = path.stat()
            except OSError:
                continue
            rel = path.relative_to(recording).as_posix()
            digest.update(f"{rel}\0{st.st_size}\0{st.st_mtime_ns}\n".encode())
            total += st.st_size
    if sizes is not None:
        sizes["bytes"] = total
    return digest.hexdigest()


def stored_run(run_dir: str | Path) -> dict | None:
    """What is stored beside a run's outputs ({"fingerprint", "status", "reason", ...}), or None (nothing,
    unreadable, other schema)."""
    try:
        data = json.loads((Path(run_dir) / FINGERPRINT_JSON).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if not isinstance(data, dict) or data.get("schema") != FINGERPRINT_SCHEMA \
            or not isinstance(data.get("fingerprint"), str) or data.get("status") not in ("ok", "failed"):
        return None
    return data


def write_fingerprint(run_dir: str | Path, fingerprint: str, recording: str | Path, version: str,
                      options: dict, status: str = "ok", reason: str = "") -> None:
    """Store ``fingerprint`` beside the run's outputs: complete ones (``status`` "ok"), or none because the
    recording is bad input (``status`` "failed" with the one-line ``reason``: the same inputs fail the same
    way, so such a run is not retried until its inputs or vibro change)."""
    atomic_write_text(Path(run_dir) / FINGERPRINT_JSON, json.dumps(
        {"schema": FINGERPRINT_SCHEMA, "fingerprint": fingerprint, "status": status, "reason": reason,
         "recording": str(recording), "vibro_version": version, "options": options}, indent=1) + "\n")


def forget_fingerprint(run_dir: str | Path) -> None:
    """Remove a stored fingerprint (before a run is redone: a crash then leaves it to be redone again)."""
    (Path(run_dir) / FINGERPRINT_JSON).unlink(missing_ok=True)
