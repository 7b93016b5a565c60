"""results.json on disk: every one vibro writes goes through :func:`write_results`, every one it reads
through :func:`read_results` (contract: docs/recording-format.md; the types: :mod:`vibro_model.results`)."""

from __future__ import annotations

import csv
import json
from pathlib import Path
from typing import Any, Mapping

from vibro_io.outputs import atomic_open, atomic_write_text
from vibro_model.codec import ResultsError
from vibro_model.results import ResultsDocument, results_text

RESULTS_JSON = "results.json"
CSV_TABLES = ("flights.csv", "impacts.csv")  # written by write_result_tables, in this order


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


def write_result_tables(doc: ResultsDocument, out_dir: str | Path) -> list[Path]:
    """flights.csv, impacts.csv (the columns of results.json's flights and impacts) in ``out_dir``, each
    written atomically; returns the paths."""
    out_dir = Path(out_dir)
    paths = []
    for name, rows in zip(CSV_TABLES, ([f.to_dict() for f in doc.flights], [i.to_dict() for i in doc.impacts])):
        path = out_dir / name
        with atomic_open(path, "w", newline="") as fh:
            if rows:
                names = list(dict.fromkeys(k for r in rows for k in r))   # optional keys of later rows too
                w = csv.DictWriter(fh, fieldnames=names)
                w.writeheader()
                w.writerows(rows)
            else:
                fh.write("index\n")
        paths.append(path)
    return paths
