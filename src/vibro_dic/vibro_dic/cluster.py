"""The Dask cluster vibro's parallel work runs on: chunked DIC (:mod:`vibro_dic.chunked`) and campaigns
(:mod:`vibro_app.campaign`).

Default: a ``distributed.LocalCluster`` of worker *processes* (not threads: DIC and the fits hold the
GIL), one thread each, as many as asked (default: the CPU cores); no dashboard. ``scheduler``: connect to
an existing cluster instead (``tcp://host:8786``); its workers must see the recordings' and outputs' paths
(a shared file system) and run the same vibro. Nothing starts at import time.
"""

from __future__ import annotations

import argparse
import logging
import os
import time
from contextlib import contextmanager
from typing import TYPE_CHECKING, Iterator

from vibro_model.errors import RecordingError

if TYPE_CHECKING:  # only for the annotation: distributed is imported where a cluster is made
    import distributed

#: seconds to wait for an existing scheduler (``--scheduler``) before giving up with one line
CONNECT_TIMEOUT_S = 10.0


def default_workers() -> int:
    """Worker processes of a local cluster when none are asked: the CPU cores this process may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return max(1, os.cpu_count() or 1)


def add_cluster_args(p: argparse.ArgumentParser, *, workers_help: str | None = None,
                     scheduler_help: str | None = None) -> None:
    """``--workers N`` / ``--scheduler ADDRESS`` (one or the other) on a subcommand's parser; the help
    texts default to DIC in chunks on Dask workers (:mod:`vibro_dic.chunked`). Imports nothing of Dask
    (the CLI parser stays light)."""
    where = p.add_mutually_exclusive_group()
    where.add_argument("--workers", type=int, default=None, metavar="N",
                       help=workers_help or "track in chunks of frames on N local worker processes (Dask); the "
                                            "same dic.csv as one process (default: one process)")
    where.add_argument("--scheduler", metavar="ADDRESS",
                       help=scheduler_help or "track in chunks on the Dask cluster at ADDRESS (e.g. "
                                              "tcp://host:8786; its workers must see the recording's path)")


def check_workers(workers: int | None, where: str = "--workers") -> int | None:
    """``workers`` if it is None or a positive integer, else :class:`RecordingError` naming ``where``."""
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int) or workers < 1):
        raise RecordingError(f"{where}: expected a positive number of worker processes, got {workers!r}")
    return workers


@contextmanager
def dask_client(workers: int | None = None, scheduler: str | None = None) -> Iterator["distributed.Client"]:
    """A ``distributed.Client`` on a new local cluster of ``workers`` processes x 1 thread (default
    :func:`default_workers`), or on the existing scheduler at ``scheduler``; closed (and the local cluster
    shut down) on exit. A scheduler that cannot be reached: :class:`RecordingError` (one line)."""
    client, cluster = open_client(workers, scheduler)
    try:
        yield client
    finally:
        close_client(client, cluster)


def open_client(workers: int | None = None, scheduler: str | None = None, *,
                list_scheduling: bool = False) -> tuple["distributed.Client", "distributed.LocalCluster | None"]:
    """(client, the local cluster or None) as :func:`dask_client` makes them; close with :func:`close_client`.

    ``list_scheduling`` (a local cluster only; campaigns): its scheduler hands each single-thread worker one
    task at a time (``worker-saturation`` 1.0; Dask's default 1.1 gives such a worker two, binding the
    second task to it while another worker may go idle), so the queued tasks start in their priority order
    on whichever worker frees first; and its worker processes skip the interpreter's teardown when they exit
    (:func:`fast_exit_at_shutdown`), which made a 2-worker cluster's close take 1.5-3.1 s instead of 0.1 s here."""
    import distributed  # noqa: F401  (its loggers exist from here on, to be quietened)

    check_workers(workers)
    with _QuietDistributed(logging.WARNING):
        client, cluster = _connect(workers, scheduler, list_scheduling=list_scheduling and scheduler is None)
        if cluster is not None and list_scheduling:
            try:
                client.run(fast_exit_at_shutdown)
            except BaseException:
                close_client(client, cluster)
                raise
    return client, cluster


def close_client(client: "distributed.Client", cluster: "distributed.LocalCluster | None") -> None:
    """Close ``client`` and shut down ``cluster`` (when not None) without Dask's shutdown chatter."""
    # at shutdown the nanny kills a worker still exiting after 4 s (its work is done): no warning for that
    with _QuietDistributed(logging.ERROR):
        client.close()
        if cluster is not None:
            cluster.close()


def fast_exit_at_shutdown() -> None:
    """In a worker process of a local cluster (``client.run``): at interpreter exit run every ``atexit``
    handler, flush stdout and stderr, then end the process with ``os._exit`` (status 0), skipping the
    interpreter's teardown of its modules and objects. After a campaign's tasks (matplotlib, scipy, numba
    loaded) that teardown took 0.4-1.3 s per process here, and the nanny waits for it when the cluster
    closes (up to 4 s, then it kills the process). The task's outputs are written and closed by then."""
    import atexit
    import sys

    def _exit() -> None:
        atexit.unregister(_exit)
        atexit._run_exitfuncs()  # the other handlers (logging's flush among them), registered before this one
        for stream in (sys.stdout, sys.stderr):
            try:
                stream.flush()
            except (OSError, ValueError, AttributeError):
                pass
        os._exit(0)

    atexit.register(_exit)


class BackgroundClient:
    """A client being connected (a local cluster started, or an existing scheduler reached, as
    :func:`open_client` does) in a background thread, so that the caller goes on with other work meanwhile.
    :meth:`result` waits for it (and raises what the start raised: :class:`RecordingError` for a scheduler
    that cannot be reached); :meth:`close` waits for the start to end and closes what it made."""

    def __init__(self, workers: int | None = None, scheduler: str | None = None, *, list_scheduling: bool = False):
        import threading

        check_workers(workers)
        self._args = (workers, scheduler, list_scheduling)
        self._client = self._cluster = self._error = None
        #: seconds the start took (None until it ended)
        self.start_s: float | None = None
        self._t0 = time.perf_counter()
        self._thread = threading.Thread(target=self._start, name="vibro-cluster-start", daemon=True)
        self._thread.start()

    def _start(self) -> None:
        workers, scheduler, list_scheduling = self._args
        try:
            self._client, self._cluster = open_client(workers, scheduler, list_scheduling=list_scheduling)
        except BaseException as exc:  # noqa: BLE001 - handed to the caller by result()
            self._error = exc
        finally:
            self.start_s = time.perf_counter() - self._t0

    def result(self) -> "distributed.Client":
        """The connected client (waits for the start to end); the start's error if it failed."""
        self._thread.join()
        if self._error is not None:
            raise self._error
        return self._client

    def close(self) -> None:
        """Wait for the start to end, then close the client and the local cluster (nothing if it failed)."""
        self._thread.join()
        if self._client is not None:
            client, cluster, self._client, self._cluster = self._client, self._cluster, None, None
            close_client(client, cluster)


class _QuietDistributed:
    """Dask's own lines below ``level`` (scheduler, nanny, worker start and stop) off unless vibro logs at
    DEBUG (-v)."""

    def __init__(self, level: int):
        self.level = level

    def __enter__(self):
        self.levels = {}
        if logging.getLogger().isEnabledFor(logging.DEBUG):
            return
        names = [n for n in logging.root.manager.loggerDict if n == "distributed" or n.startswith("distributed.")]
        for name in names:  # distributed sets levels on its sub-loggers itself
            logger = logging.getLogger(name)
            self.levels[name] = logger.level
            if logger.getEffectiveLevel() < self.level:
                logger.setLevel(self.level)

    def __exit__(self, *exc):
        for name, level in self.levels.items():
            logging.getLogger(name).setLevel(level)


def _connect(workers: int | None, scheduler: str | None, *, list_scheduling: bool = False):
    """(client, local cluster or None); ``list_scheduling``: see :func:`open_client`."""
    import dask
    from distributed import Client, LocalCluster

    if scheduler is not None:
        try:
            client = Client(scheduler, timeout=CONNECT_TIMEOUT_S)
        except (OSError, TimeoutError, ValueError) as exc:
            raise RecordingError(f"--scheduler {scheduler}: cannot connect to a Dask scheduler there "
                                 f"({type(exc).__name__}: {' '.join(str(exc).split()) or 'no answer'})") from None
        return client, None
    # the scheduler of a local cluster runs in this process and reads worker-saturation when it is made
    config = {"distributed.scheduler.worker-saturation": 1.0} if list_scheduling else {}
    with dask.config.set(config):
        cluster = LocalCluster(n_workers=workers or default_workers(), threads_per_worker=1, processes=True,
                               dashboard_address=None, silence_logs=logging.ERROR,
                               # no dashboard; the scheduler's own HTTP routes on a free loopback port (not 8787)
                               scheduler_kwargs={"dashboard": False, "dashboard_address": "127.0.0.1:0"})
    try:
        return Client(cluster), cluster
    except BaseException:
        cluster.close()
        raise
