"""What a node's exit means for its run: finished, restart it, or end the whole run (and why).

One rule for both process supervisors of the graph: ``vibro graph`` (:mod:`vibro_bringup.supervisor`) and the
launch file's event handlers (``launch/vibro.launch.py``) call :func:`exit_verdict`, so a lab's ``ros2 launch``
ends a run exactly where ``vibro graph`` does. Exit codes of the nodes (:func:`vibro_ros.node_support.run_node`):
0 finished (its stream ended, or SIGINT/SIGTERM), :data:`REFUSED` (2) bad input or parameters, or another run's
data (vibro_ros.guard): a restart would refuse again; :data:`INCOMPLETE` (3) the run lost frames the graph never
tracked, so the end-of-run judges (discrepancy) judged nothing; anything else (1, or a signal: negative) a crash.
"""

from __future__ import annotations

import signal
from dataclasses import dataclass

from vibro_ros.exit_codes import INCOMPLETE, REFUSED

__all__ = ["END_RUN", "FINISHED", "INCOMPLETE", "REFUSED", "RESTART", "ExitVerdict", "describe_exit", "exit_verdict"]

FINISHED = "finished"
RESTART = "restart"
END_RUN = "end_run"


@dataclass(frozen=True)
class ExitVerdict:
    """``action``: :data:`FINISHED` (nothing to do), :data:`RESTART` or :data:`END_RUN`; ``reason``: one line
    naming the node, how it exited and what follows (empty for a node that finished)."""

    action: str
    reason: str = ""


def describe_exit(code: int) -> str:
    """``exit code 1``, or ``killed by SIGKILL`` for a negative (signal) code as subprocess and launch give it."""
    if code < 0:
        try:
            return f"killed by {signal.Signals(-code).name}"
        except ValueError:
            return f"killed by signal {-code}"
    return f"exit code {code}"


def exit_verdict(name: str, role: str, code: int, *, restarts_done: int, respawn_max: int,
                 live: bool = False) -> ExitVerdict:
    """The verdict on node ``name`` (its graph_spec role: source, processing, sink, viewer) exiting with ``code``
    after ``restarts_done`` restarts.

    From a recording (``live`` False) a node that exits 0 has finished. A processing node or viewer that crashed
    is restarted while ``restarts_done < respawn_max``; a source or the recorder (sink) that crashed ends the
    run (no more data can come, or none is recorded: the others would wait forever), and so does a processing
    node out of restarts. Live, nodes never finish by themselves: a processing node or viewer is restarted
    whatever its code (``respawn_max`` does not apply: a lab session keeps going); the recorder that stops
    ends the run. A :data:`REFUSED` exit always ends the run: the same input would be refused again.
    """
    restartable = role in ("processing", "viewer")
    if code == REFUSED:
        return ExitVerdict(END_RUN, f"{name} refused its input or parameters (exit code {REFUSED}; its log says "
                                    "why): not restarted, the run ends")
    if code == INCOMPLETE:
        return ExitVerdict(END_RUN, f"{name}: the run is incomplete (exit code {INCOMPLETE}; its log says which frames "
                                    "were never tracked): its results are not judged, the run ends")
    if code == 0 and not live:
        return ExitVerdict(FINISHED)
    how = "stopped (exit code 0)" if code == 0 else describe_exit(code)
    if restartable and (live or restarts_done < respawn_max):
        limit = "" if live else f"/{respawn_max}"
        return ExitVerdict(RESTART, f"{name} {how}; restarting it ({restarts_done + 1}{limit})")
    if restartable:
        return ExitVerdict(END_RUN, f"{name} {how} after {restarts_done} restart(s), its last: the run ends")
    if role == "source":
        return ExitVerdict(END_RUN, f"{name} {how}: no more input can come, the run ends (its readers would wait "
                                    "for its end of stream forever)")
    if role == "sink":
        return ExitVerdict(END_RUN, f"{name} {how}: nothing more is recorded, the run ends")
    return ExitVerdict(END_RUN, f"{name} {how}: the run ends")
