""":func:`run_campaign`: every run of a campaign analysed on a Dask cluster (one task per recording), then
the campaign report. Runs whose outputs are up to date are not redone (:mod:`.fingerprint`); a run that
fails is reported with its reason and the others go on."""

from __future__ import annotations

import sys
import time
from datetime import datetime, timezone
from pathlib import Path

from vibro_app.campaign.fingerprint import code_version, input_fingerprint, stored_run
from vibro_app.campaign.report import (
    FIGURES,
    FLAG_RULE,
    SCHEMA,
    write_campaign_csv,
    write_campaign_json,
    write_figures,
    write_report_html,
)
from vibro_app.campaign.runs import RunSpec, find_runs
from vibro_app.campaign.summary import flag_disagreeing, orientation_groups, run_summary
from vibro_app.campaign.task import analyze_run
from vibro_io.outputs import OutputError


def _resumed_record(spec: RunSpec, run_dir: Path, fingerprint: str) -> dict | None:
    """The record of a run that need not be redone (its stored fingerprint matches), else None."""
    stored = stored_run(run_dir)
    if stored is None or stored["fingerprint"] != fingerprint:
        return None
    if stored["status"] == "ok" and not (run_dir / "results.json").is_file():
        return None
    return {"name": spec.name, "recording": str(spec.path), "status": stored["status"],
            "reason": str(stored.get("reason") or ""), "resumed": True, "warnings": [], "task_s": 0.0}


def _prepare_out(out: Path) -> None:
    if out.exists() and not out.is_dir():
        raise OutputError(f"{out}: exists and is not a folder")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(f"{out}: cannot create the folder ({exc.strerror or exc})") from None


def _run_tasks(todo: list[tuple[RunSpec, Path, str]], options: dict, version: str, *, workers: int | None,
               scheduler: str | None, progress: bool, done: int, total: int) -> tuple[list[dict], dict]:
    """The records of the runs in ``todo`` (analysed on the cluster) and the cluster timing."""
    from distributed import as_completed
    from tqdm import tqdm

    from vibro_dic.cluster import dask_client

    timing = {}
    records = []
    t0 = time.perf_counter()
    with dask_client(workers, scheduler) as client:
        timing["cluster_start_s"] = time.perf_counter() - t0
        timing["n_workers"] = len(client.scheduler_info(n_workers=-1).get("workers", {}))
        futures = {client.submit(analyze_run, spec.name, str(spec.path), str(run_dir), options, fp, version,
                                 pure=False): spec for spec, run_dir, fp in todo}
        bar = tqdm(total=total, initial=done, unit="run", desc="campaign", disable=not progress, file=sys.stderr)
        t1 = time.perf_counter()
        try:
            for future in as_completed(futures):
                spec = futures[future]
                try:
                    record = future.result()
                except Exception as exc:  # noqa: BLE001 - a worker died (memory, signal): that run failed
                    record = {"name": spec.name, "recording": str(spec.path), "status": "failed",
                              "reason": f"worker failed: {type(exc).__name__}: {' '.join(str(exc).split())}",
                              "warnings": [], "task_s": None}
                records.append(record)
                bar.update(1)
                if record["status"] != "ok":
                    bar.write(f"vibro campaign: {record['name']}: failed: {record['reason']}", file=sys.stderr)
        finally:
            bar.close()
        timing["tasks_wall_s"] = time.perf_counter() - t1
    return records, timing


def run_campaign(source: str | Path, out: str | Path, *, workers: int | None = None, scheduler: str | None = None,
                 method: str = "paper", dic_method: str = "icgn", weights: str | None = None,
                 progress: bool = False) -> dict:
    """Analyse every run of ``source`` (a folder or a list file: :mod:`.runs`) into ``out/<run>/`` and write
    the campaign report into ``out`` (:mod:`.report`); returns the campaign document (campaign.json).

    ``workers``: processes of the local cluster (default: the CPU cores); ``scheduler``: an existing Dask
    cluster's address instead. Up-to-date runs are not redone and no cluster is started when none is left.
    Bad input of the campaign itself (no runs, an unusable ``out``): :class:`RecordingError`; a bad
    recording only fails its run."""
    from vibro_dic.cluster import check_workers

    start = time.perf_counter()
    check_workers(workers)
    out = Path(out)
    _prepare_out(out)
    runs = find_runs(source, exclude=out)
    version = code_version()
    options = {"method": method, "dic_method": dic_method, "weights": weights}
    todo, records = [], []
    for spec in runs:
        run_dir = out / spec.name
        fp = input_fingerprint(spec.path, options, version)
        resumed = _resumed_record(spec, run_dir, fp)
        if resumed is not None:
            records.append(resumed)
        elif not (spec.path / "rig.yaml").is_file():  # a listed folder that is not there: no task for that
            what = "no rig.yaml in it" if spec.path.is_dir() else "no such folder"
            records.append({"name": spec.name, "recording": str(spec.path), "status": "failed",
                            "reason": f"{spec.path}: not a recording directory ({what})", "resumed": False,
                            "warnings": [], "task_s": None})
        else:
            todo.append((spec, run_dir, fp))
    timing = {"cluster_start_s": None, "tasks_wall_s": None, "n_workers": None}
    if todo:
        fresh, timing = _run_tasks(todo, options, version, workers=workers, scheduler=scheduler,
                                   progress=progress, done=len(records), total=len(runs))
        records += fresh
    by_name = {r["name"]: r for r in records}
    rows = [run_summary(by_name[spec.name], out / spec.name) for spec in runs]
    for row in rows:
        row.setdefault("resumed", False)
    flag_disagreeing(rows)
    failed = [{"name": r["name"], "reason": r["reason"]} for r in rows if r["status"] != "ok"]
    document = {
        "schema": SCHEMA,
        "created_utc": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "source": str(source),
        "out": str(out),
        "vibro_version": version,
        "options": options,
        "cluster": {"scheduler": scheduler, "workers": workers},
        "flag_rule": FLAG_RULE,
        "summary": {"n_runs": len(rows), "n_ok": sum(r["status"] == "ok" for r in rows),
                    "n_resumed": sum(bool(r["resumed"]) and r["status"] == "ok" for r in rows),
                    "n_failed": len(failed), "n_flagged": sum(bool(r["flags"]) for r in rows),
                    "failed": failed,
                    "flagged": [{"name": r["name"], "flags": r["flags"]} for r in rows if r["flags"]]},
        "timing": timing,
        "runs": rows,
    }
    document["orientation"] = orientation_groups(rows)   # COR per rig orientation (setup.axis_tilt_deg)
    figures = write_figures(out, rows)
    document["figures"] = {k: FIGURES[k] for k in figures}
    document["timing"]["wall_s"] = time.perf_counter() - start
    write_campaign_json(out, document)
    write_campaign_csv(out, rows)
    write_report_html(out, document, figures)
    return document


