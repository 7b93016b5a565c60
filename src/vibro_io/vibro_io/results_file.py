"""results.json on disk: every one vibro writes goes through :func:`write_results`, every one it reads
through :func:`read_results` (contract: docs/recording-format.md; the types: :mod:`vibro_model.results`)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Mapping

from vibro_io.outputs import atomic_write_text
from vibro_model.codec import ResultsError
from vibro_model.results import ResultsDocument, results_text


def write_results(path: str | Path, doc: ResultsDocument | Mapping[str, Any]) -> Path:
    """Write results.json (a document or a mapping, validated first) atomically: a crash never leaves a
    half-written file. Returns the path."""
    return atomic_write_text(Path(path), results_text(doc))


def read_results(path: str | Path) -> ResultsDocument:
    """Read and validate a results.json; :class:`ResultsError` names the file and the key at fault."""
    path = Path(path)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise ResultsError(f"{path}: cannot read ({exc.strerror or exc})") from None
    except ValueError as exc:
        raise ResultsError(f"{path}: not JSON ({exc})") from None
    return ResultsDocument.from_dict(data, str(path))
