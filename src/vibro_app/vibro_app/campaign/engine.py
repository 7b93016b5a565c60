""":func:`run_campaign`: every run of a campaign analysed on a Dask cluster (one task per recording), then
the campaign report. Runs whose outputs are up to date are not redone (:mod:`.fingerprint`); a run that
fails is reported with its reason and the others go on.

What keeps the serial part short (docs/campaigns.md, *Scheduling*): the cluster starts in the background as
soon as some run surely needs work, while the runs are fingerprinted; the runs go longest first (the
recordings' bytes, Dask priorities; the local cluster hands each worker one task at a time); each run's row is
made as it finishes, the report's imports happen during the tasks and the cluster closes while the report is
written (its workers skip the interpreter's teardown)."""

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
from vibro_dic import cluster as dic_cluster
from vibro_io.outputs import OutputError


def _resumed_record(spec: RunSpec, stored: dict | None, run_dir: Path, fingerprint: str) -> dict | None:
    """The record of a run that need not be redone (its ``stored`` fingerprint matches), else None."""
    if stored is None or stored["fingerprint"] != fingerprint:
        return None
    if stored["status"] == "ok" and not (run_dir / "results.json").is_file():
        return None
    return {"name": spec.name, "recording": str(spec.path), "status": stored["status"],
            "reason": str(stored.get("reason") or ""), "resumed": True, "warnings": [], "task_s": 0.0}


def _surely_redone(spec: RunSpec, stored: dict | None, run_dir: Path) -> bool:
    """Whether the run is redone whatever its fingerprint: a recording with nothing stored for it (or stored
    as analysed but without its results.json). Such a run starts the cluster before any fingerprint is made."""
    if not (spec.path / "rig.yaml").is_file():
        return False  # no task for it: failed before any cluster
    return stored is None or (stored["status"] == "ok" and not (run_dir / "results.json").is_file())


def longest_first(todo: list[tuple[RunSpec, Path, str, int]]) -> list[tuple[RunSpec, Path, str, int]]:
    """``todo`` (spec, run dir, fingerprint, cost) in submission order: the largest estimated cost (the
    recording's bytes on disk) first, then by name. Longest-first list scheduling: each worker takes the
    next run when it frees, so a long run never starts last and holds up the end of the campaign."""
    return sorted(todo, key=lambda item: (-item[3], item[0].name))


def _prepare_out(out: Path) -> None:
    if out.exists() and not out.is_dir():
        raise OutputError(f"{out}: exists and is not a folder")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(f"{out}: cannot create the folder ({exc.strerror or exc})") from None


def _warm_report_imports() -> None:
    """Import what the report needs (matplotlib, its Agg backend, scipy.stats), in a thread while the tasks
    run: about 1 s taken off the serial part after the last task."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot  # noqa: F401
    import scipy.stats  # noqa: F401

    import vibro_app.report  # noqa: F401


def _run_tasks(client, todo: list[tuple[RunSpec, Path, str, int]], options: dict, version: str, *,
               progress: bool, done: int, total: int, on_record) -> dict:
    """Submit the runs of ``todo`` longest first (:func:`longest_first`, Dask priorities in the same order)
    and hand each run's record to ``on_record`` as it finishes; the timing of the tasks."""
    from distributed import as_completed
    from tqdm import tqdm

    timing = {"n_workers": len(client.scheduler_info(n_workers=-1).get("workers", {}))}
    order = longest_first(todo)
    t1 = time.perf_counter()
    # the first submitted has the highest priority: Dask starts queued tasks by priority, whatever the order in
    # which they reach the scheduler
    futures = {client.submit(analyze_run, spec.name, str(spec.path), str(run_dir), options, fp, version,
                             pure=False, priority=len(order) - rank): spec
               for rank, (spec, run_dir, fp, _) in enumerate(order)}
    timing["schedule"] = {"order": "longest first: the recording's bytes on disk, largest first",
                          "runs": [{"name": spec.name, "cost_bytes": cost, "priority": len(order) - rank}
                                   for rank, (spec, _, _, cost) in enumerate(order)]}
    bar = tqdm(total=total, initial=done, unit="run", desc="campaign", disable=not progress, file=sys.stderr)
    summaries_s = 0.0
    try:
        for future in as_completed(futures):
            spec = futures[future]
            try:
                record = future.result()
            except Exception as exc:  # noqa: BLE001 - a worker died (memory, signal): that run failed
                record = {"name": spec.name, "recording": str(spec.path), "status": "failed",
                          "reason": f"worker failed: {type(exc).__name__}: {' '.join(str(exc).split())}",
                          "warnings": [], "task_s": None}
            t = time.perf_counter()
            on_record(record)  # its campaign row, made while the other tasks run
            summaries_s += time.perf_counter() - t
            bar.update(1)
            if record["status"] != "ok":
                bar.write(f"vibro campaign: {record['name']}: failed: {record['reason']}", file=sys.stderr)
    finally:
        bar.close()
    timing["tasks_wall_s"] = time.perf_counter() - t1
    timing["summaries_in_loop_s"] = summaries_s
    return timing


def _plan_runs(runs: list[RunSpec], stored: dict, out: Path, options: dict, version: str,
               start_cluster) -> tuple[list, list[dict]]:
    """(the runs to analyse: (spec, run folder, fingerprint, bytes), the records of the others: up to date, or not
    a recording); ``start_cluster`` is called as soon as a run needs work."""
    todo, records = [], []
    for spec in runs:
        run_dir = out / spec.name
        sizes: dict = {}
        fp = input_fingerprint(spec.path, options, version, sizes=sizes)
        resumed = _resumed_record(spec, stored[spec.name], run_dir, fp)
        if resumed is not None:
            records.append(resumed)
        elif not (spec.path / "rig.yaml").is_file():  # a listed folder that is not there: no task for that
            what = "no rig.yaml in it" if spec.path.is_dir() else "no such folder"
            records.append({"name": spec.name, "recording": str(spec.path), "status": "failed",
                            "reason": f"{spec.path}: not a recording directory ({what})", "resumed": False,
                            "warnings": [], "task_s": None})
        else:
            todo.append((spec, run_dir, fp, sizes["bytes"]))
            start_cluster()  # a fingerprint that differs: that run is redone
    return todo, records


def _campaign_document(rows: list[dict], timing: dict, *, source, out: Path, version: str, options: dict,
                       cluster: dict) -> dict:
    """campaign.json's document of the finished ``rows`` (flags and the orientation groups made here)."""
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
        "cluster": cluster,
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
    return document


def _write_report(out: Path, document: dict, rows: list[dict], after: dict) -> None:
    """The campaign's figures, CSV and report.html (``document["figures"]`` set), each part's seconds in
    ``after``."""
    t = time.perf_counter()
    figures = write_figures(out, rows)
    document["figures"] = {k: FIGURES[k] for k in figures}
    after["figures_s"] = time.perf_counter() - t
    t = time.perf_counter()
    write_campaign_csv(out, rows)
    after["campaign_csv_s"] = time.perf_counter() - t
    t = time.perf_counter()
    write_report_html(out, document, figures)
    after["report_html_s"] = time.perf_counter() - t


def run_campaign(source: str | Path, out: str | Path, *, workers: int | None = None, scheduler: str | None = None,
                 method: str = "paper", dic_method: str = "icgn", weights: str | None = None,
                 progress: bool = False) -> dict:
    """Analyse every run of ``source`` (a folder or a list file: :mod:`.runs`) into ``out/<run>/`` and write
    the campaign report into ``out`` (:mod:`.report`); returns the campaign document (campaign.json).

    ``workers``: processes of the local cluster (default: the CPU cores); ``scheduler``: an existing Dask
    cluster's address instead. Up-to-date runs are not redone and no cluster is started when none is left.
    The cluster starts in the background as soon as some run surely needs work (nothing stored for it, or
    a fingerprint that differs), while the other runs are fingerprinted; runs are submitted longest first
    (:func:`longest_first`); each run's row is made as it finishes. Bad input of the campaign itself (no
    runs, an unusable ``out``): :class:`RecordingError`; a bad recording only fails its run."""
    start = time.perf_counter()
    import threading

    dic_cluster.check_workers(workers)
    out = Path(out)
    _prepare_out(out)
    runs = find_runs(source, exclude=out)
    version = code_version()
    options = {"method": method, "dic_method": dic_method, "weights": weights}
    cluster: dic_cluster.BackgroundClient | None = None
    closing: threading.Thread | None = None  # the cluster being closed while the report is written

    def start_cluster() -> None:
        nonlocal cluster
        if cluster is None:
            cluster = dic_cluster.BackgroundClient(workers, scheduler, list_scheduling=True)

    timing = {"cluster_start_s": None, "tasks_wall_s": None, "n_workers": None}
    try:
        stored = {spec.name: stored_run(out / spec.name) for spec in runs}
        if any(_surely_redone(spec, stored[spec.name], out / spec.name) for spec in runs):
            start_cluster()  # starts while the runs are fingerprinted
        todo, records = _plan_runs(runs, stored, out, options, version, start_cluster)
        timing["prepare_s"] = time.perf_counter() - start
        rows_by_name = {r["name"]: run_summary(r, out / r["name"]) for r in records}
        if todo:
            t0 = time.perf_counter()
            client = cluster.result()
            timing["cluster_wait_s"] = time.perf_counter() - t0
            timing["cluster_start_s"] = cluster.start_s
            warm = threading.Thread(target=_warm_report_imports, name="vibro-report-imports", daemon=True)
            warm.start()
            timing.update(_run_tasks(
                client, todo, options, version, progress=progress, done=len(records), total=len(runs),
                on_record=lambda r: rows_by_name.__setitem__(r["name"], run_summary(r, out / r["name"]))))
            t_last = time.perf_counter()
            closing = threading.Thread(target=cluster.close, name="vibro-cluster-close", daemon=True)
            closing.start()  # the workers exit while the report is written
            warm.join()
            timing["after_tasks"] = {"report_imports_wait_s": time.perf_counter() - t_last}
        else:
            timing["after_tasks"] = {}
        after = timing["after_tasks"]
        t = time.perf_counter()
        rows = [rows_by_name[spec.name] for spec in runs]
        document = _campaign_document(rows, timing, source=source, out=out, version=version, options=options,
                                      cluster={"scheduler": scheduler, "workers": workers})
        after["flags_orientation_s"] = time.perf_counter() - t
        _write_report(out, document, rows, after)
        if closing is not None:
            t = time.perf_counter()
            closing.join()
            after["cluster_close_wait_s"] = time.perf_counter() - t
        document["timing"]["wall_s"] = time.perf_counter() - start  # all but writing campaign.json itself
        write_campaign_json(out, document)
    finally:
        if closing is not None:
            closing.join()
        elif cluster is not None:
            cluster.close()
    return document
