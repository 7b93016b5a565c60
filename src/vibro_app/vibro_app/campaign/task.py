"""The Dask task of one campaign run: ``vibro analyze``'s core on one recording, never raising.

:func:`analyze_run` calls :func:`vibro_app.analyze.analyze_recording` (the same call as ``vibro
analyze RECORDING --out OUT/<run> --overwrite``; DIC in this worker process), then stores the run's
fingerprint (:mod:`.fingerprint`). It returns a plain record: ``status`` "ok" or "failed", ``reason`` (one
line: a bad recording's :class:`RecordingError` message (remembered with the fingerprint), or the type
and message of an unexpected error, whose traceback is kept in ``traceback``), the warnings vibro logged
while analysing it, and the task's own wall time (s) and worker.
"""

from __future__ import annotations

import logging
import os
import time
import traceback
from pathlib import Path

from vibro_app.campaign.fingerprint import forget_fingerprint, write_fingerprint
from vibro_model.errors import RecordingError


class _WarningCollector(logging.Handler):
    """Keeps the WARNING (and worse) lines that vibro logs during one run (they go to the run's record)."""

    def __init__(self) -> None:
        super().__init__(logging.WARNING)
        self.lines: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        if record.name.startswith("vibro"):
            self.lines.append(f"{record.name}: {' '.join(record.getMessage().split())}")


def analyze_run(name: str, recording: str, run_dir: str, options: dict, fingerprint: str, version: str) -> dict:
    """Analyse one recording into ``run_dir`` (see module doc); the record of the run."""
    from vibro_app.analyze import DicPlan, FitPlan, analyze_recording

    start = time.perf_counter()
    record = {"name": name, "recording": recording, "status": "ok", "reason": "", "warnings": [],
              "worker_pid": os.getpid()}
    collector = _WarningCollector()
    root = logging.getLogger()
    root.addHandler(collector)
    try:
        Path(run_dir).mkdir(parents=True, exist_ok=True)
        forget_fingerprint(run_dir)
        analyze_recording(recording, run_dir, progress=False, overwrite=True,
                          fit=FitPlan(method=options["method"], weights=options["weights"]),
                          dic=DicPlan(method=options["dic_method"]))
        write_fingerprint(run_dir, fingerprint, recording, version, options)
    except RecordingError as exc:
        record.update(status="failed", reason=" ".join(str(exc).split()))
        try:  # bad input fails the same way until the inputs change: remembered (fingerprint module doc)
            write_fingerprint(run_dir, fingerprint, recording, version, options, "failed", record["reason"])
        except (RecordingError, OSError):
            pass
    except Exception as exc:  # noqa: BLE001 - one bad recording is reported, never fatal to the campaign
        record.update(status="failed", reason=f"internal error: {type(exc).__name__}: {' '.join(str(exc).split())}",
                      traceback=traceback.format_exc())
    finally:
        root.removeHandler(collector)
    record["warnings"] = collector.lines
    record["task_s"] = time.perf_counter() - start
    return record
