"""The process supervisor of ``vibro graph``: start, watch, restart and stop the node processes.

Driven by the node table (:class:`vibro_bringup.graph_spec.NodeSpec` roles): processes start in the
order viewer (the Foxglove bridge: up before anything streams), sink, processing, sources (not needed
for correctness -- the nodes wait for their declared readers by name -- but the sources then find their
readers at once). A node that exits with code 0 has finished by itself (its stream ended). A processing
node that crashes is restarted, like launch's ``respawn``, at most ``respawn`` times, its log
appended; any other non-zero exit (a source, the recorder, restarts used up, a refusal: exit code 2) is a
failure reported at once with the last lines of the node's log (:func:`vibro_bringup.exit_policy.exit_verdict`,
the rule the launch file follows too). :meth:`Supervisor.stop` stops what still runs in the order
sources, processing, (drain) sinks, viewer, so the recorder takes the last messages before it closes.
"""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Sequence

from vibro_ros.entry import STACK_DUMP_SIGNAL

from .exit_policy import FINISHED, RESTART, exit_verdict
from .graph_spec import VIEWER, NodeSpec, status_streams

START_ORDER = (VIEWER, "sink", "processing", "source")
STOP_ORDER = ("source", "processing", "sink", VIEWER)
#: lines of a killed node's log announced (its threads' stacks, a few frames each, and what it said last)
KILLED_LOG_LINES = 40


@dataclass(frozen=True)
class Failure:
    """A node that exited with a non-zero code and was not (or no longer) restarted."""

    name: str
    code: int
    restarts: int
    log: Path
    tail: str

    def describe(self) -> str:
        again = f" after {self.restarts} restart(s)" if self.restarts else ""
        lines = "\n".join(f"  | {line}" for line in self.tail.splitlines())
        return f"{self.name} exited with code {self.code}{again}; last lines of {self.log}:\n{lines}"


def log_tail(path: Path, lines: int = 8) -> str:
    """The last ``lines`` non-empty lines of a log file ('' when unreadable)."""
    try:
        text = path.read_text(encoding="utf-8", errors="replace")
    except OSError:
        return ""
    return "\n".join([line for line in text.splitlines() if line.strip()][-lines:])


class Supervisor:
    """Processes of one graph run; ``command(spec)`` gives the argv that starts a node."""

    def __init__(self, specs: Sequence[NodeSpec], command: Callable[[NodeSpec], list[str]], log_dir: Path,
                 env: dict[str, str] | None = None, respawn: int = 2, announce: Callable[[str], None] | None = None):
        self.specs = {s.name: s for s in specs}
        self.command = command
        self.log_dir = Path(log_dir)
        self.env = env
        self.respawn = max(0, int(respawn))
        self.announce = announce or (lambda text: print(text, file=sys.stderr, flush=True))
        self.procs: dict[str, subprocess.Popen] = {}
        self.logs: dict[str, Path] = {}
        self.restarts: dict[str, int] = {}
        self.finished: set[str] = set()   # exited with code 0 by themselves
        self.failures: list[Failure] = []

    # ------------------------------------------------------------------ start
    def start_all(self, roles: Sequence[str] = START_ORDER) -> None:
        """Start the nodes of ``roles``, role by role in that order."""
        for role in roles:
            for spec in self.specs.values():
                if spec.role == role:
                    self.start(spec)

    def start(self, spec: NodeSpec, append: bool = False) -> None:
        log = self.log_dir / f"{spec.name}.log"
        self.logs[spec.name] = log
        with log.open("a" if append else "w") as out:  # the child keeps its own descriptor
            self.procs[spec.name] = subprocess.Popen(self.command(spec), stdout=out, stderr=subprocess.STDOUT,
                                                     env=self.env)

    # ------------------------------------------------------------------ watch
    def poll(self) -> list[Failure]:
        """Note the nodes that exited since the last call: finished (code 0), restarted (a processing
        node with restarts left), or failed. Returns the new failures."""
        new = []
        for name, proc in list(self.procs.items()):
            code = proc.poll()
            if code is None or name in self.finished or any(f.name == name for f in self.failures):
                continue
            spec = self.specs[name]
            done = self.restarts.get(name, 0)
            verdict = exit_verdict(name, spec.role, code, restarts_done=done, respawn_max=self.respawn)
            if verdict.action == FINISHED:
                self.finished.add(name)
                continue
            if verdict.action == RESTART:
                self.restarts[name] = done + 1
                with self.logs[name].open("a") as out:
                    out.write(f"\n--- vibro graph: {name} exited with {code}; "
                              f"restarted ({done + 1}/{self.respawn}) ---\n")
                self.start(spec, append=True)
                self.announce(f"{name} exited with {code}; restarted ({done + 1}/{self.respawn})")
                continue
            failure = Failure(name, code, done, self.logs[name], log_tail(self.logs[name]))
            self.failures.append(failure)
            new.append(failure)
        return new

    def running(self) -> list[str]:
        return [n for n, p in self.procs.items() if p.poll() is None]

    def all_finished(self) -> bool:
        """Every node has exited with code 0 by itself (a viewer is not waited for: :meth:`stop` ends it)."""
        return not self.failures and self.finished >= {n for n, s in self.specs.items() if s.role != VIEWER}

    def lingering(self, streams_ended: set[str]) -> list[str]:
        """Nodes still running although their work is over: every status stream they announce
        (:func:`vibro_bringup.graph_spec.status_streams`; at least one) has ended (``streams_ended``, as the
        monitor saw vibro/status), and every other node (a viewer aside) has finished by itself, the recorder
        among them, so nobody waits for them any more. A node that stays up then is hung (seen once in CI: a
        trajectory_fitter up 200 s after its final outputs, deaf to SIGINT); the graph runner stops it."""
        over = {n for n in self.running() if self.specs[n].role != VIEWER
                and (streams := status_streams(self.specs[n])) and streams <= streams_ended}
        others = {n for n, s in self.specs.items() if s.role != VIEWER} - over
        if self.failures or not others <= self.finished:
            return []
        return sorted(over)

    # ------------------------------------------------------------------ stop
    def stop(self, grace_s: float = 20.0, drain_s: float = 1.0, names: Sequence[str] | None = None) -> list[str]:
        """SIGINT what still runs (of ``names``; None: every node): sources, then processing nodes, then (after
        ``drain_s``, so they take the last messages) the sinks; each group waited for; SIGKILL after ``grace_s`` in
        all, each node killed first asked for its threads' stacks (:meth:`dump_stacks`) and announced with the
        end of its log. Returns the names of nodes that had to be killed."""
        deadline = time.monotonic() + grace_s
        chosen = set(self.procs if names is None else names)
        killed: list[str] = []
        for role in STOP_ORDER:
            group = [n for n in self.procs if self.specs[n].role == role and n in chosen]
            if role == "sink" and any(self.procs[n].poll() is None for n in group):
                time.sleep(drain_s)
            killed += self._interrupt(group, deadline)
        for name in killed:
            lines = "\n".join(f"  | {line}" for line in log_tail(self.logs[name], KILLED_LOG_LINES).splitlines())
            self.announce(f"vibro graph: {name} did not stop within {grace_s:g} s of SIGINT and was killed; its "
                          f"threads' stacks and the last lines of {self.logs[name]}:\n{lines}")
        return killed

    def dump_stacks(self, name: str, wait_s: float = 1.0) -> None:
        """Ask node ``name`` for the Python stack of each of its threads, written to its log
        (:data:`vibro_ros.entry.STACK_DUMP_SIGNAL`, installed by every node's process), and give it ``wait_s``
        to write them."""
        proc = self.procs[name]
        if proc.poll() is None:
            proc.send_signal(STACK_DUMP_SIGNAL)
            try:
                proc.wait(timeout=wait_s)
            except subprocess.TimeoutExpired:
                pass

    def _interrupt(self, names: list[str], deadline: float) -> list[str]:
        for name in names:
            if self.procs[name].poll() is None:
                self.procs[name].send_signal(signal.SIGINT)
        killed = []
        for name in names:
            proc = self.procs[name]
            try:
                proc.wait(timeout=max(0.1, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                self.dump_stacks(name)
                proc.kill()
                proc.wait()
                killed.append(name)
        return killed
