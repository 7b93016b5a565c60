"""CPU time per process of a bench's ROS nodes, sampled from /proc (shared by the bench scripts)."""

from __future__ import annotations

import os
import threading
import time
from pathlib import Path

CLK_TCK = os.sysconf("SC_CLK_TCK")
#: the key of a snapshot's busy CPU seconds of the whole machine (every process, all cores: /proc/stat)
MACHINE = "_machine_busy"
#: the key of the CPU seconds of every other process (not this bench's) alive at both ends of the time asked
OTHERS = "_others"


def machine_busy_s() -> float:
    """CPU seconds all cores have spent busy since boot (/proc/stat: everything but idle and iowait)."""
    try:
        fields = Path("/proc/stat").read_text().split("\n", 1)[0].split()[1:]
        ticks = [int(x) for x in fields[:8]]  # user nice system idle iowait irq softirq steal
    except (OSError, ValueError):
        return 0.0
    return (sum(ticks) - ticks[3] - ticks[4]) / CLK_TCK


def process_name(cmd: list[bytes]) -> str | None:
    """The node name of a bench process from its command line, or None for other processes.

    ``vibro_bringup.child <module>`` (vibro graph's children), a ``-r __node:=<name>`` remap (nodes
    started as launch does, and the bench's own camera/probe processes), ``vibro_app.cli`` (vibro
    graph's monitor) or ``python -m <module>_node``.
    """
    if b"vibro_bringup.child" in cmd:
        return cmd[cmd.index(b"vibro_bringup.child") + 1].decode().rsplit(".", 1)[-1]
    for arg in cmd:
        if arg.startswith(b"__node:="):
            return arg[len(b"__node:="):].decode()
    if b"vibro_app.cli" in cmd:
        return "vibro graph (monitor)"
    if len(cmd) > 2 and cmd[1] == b"-m" and cmd[2].endswith(b"_node"):
        return cmd[2].decode().rsplit(".", 1)[-1]
    return None


class CpuSampler:
    """Samples the CPU time (s) of this bench's node processes (by ROS_DOMAIN_ID) every 0.1 s."""

    def __init__(self, domain: str, period_s: float = 0.1, machine: bool = False):
        self.domain = domain.encode()
        self.machine = machine  # also the whole machine's busy CPU (key MACHINE)
        self._names: dict[str, str | None] = {}  # pid -> bench name, None: not one of this bench's
        self._others: dict[int, dict[str, float]] = {}  # sample number -> {pid: CPU s} of the other processes
        self._comm: dict[str, str] = {}  # pid -> command line (its first 80 characters) of the other processes
        self.period_s = period_s
        self.samples: list[tuple[float, dict[str, float]]] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def __enter__(self) -> "CpuSampler":
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join()

    def _name_of(self, pid: str) -> str | None:
        """The bench name of process ``pid`` in this domain, else None; remembered (a process not of this bench is
        remembered so only once it is 2 s old: just forked, it may not have exec'd its own command line yet)."""
        if pid in self._names:
            return self._names[pid]
        name = process_name(Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0"))
        if name is not None and b"ROS_DOMAIN_ID=" + self.domain not in \
                Path(f"/proc/{pid}/environ").read_bytes().split(b"\0"):
            name = None
        if name is not None:
            self._names[pid] = name
        else:
            start_s = int(Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[19]) / CLK_TCK
            if float(Path("/proc/uptime").read_text().split()[0]) - start_s > 2.0:
                self._names[pid] = None
        return name

    def _snapshot(self) -> dict[str, float]:
        # the machine's busy time read before and after the processes' (their mean): the same moment to within the
        # snapshot's own few milliseconds
        before = machine_busy_s() if self.machine else 0.0
        snap, others = {}, {}
        for pid in os.listdir("/proc"):
            if not pid.isdigit():
                continue
            try:
                name = self._name_of(pid)
                if name is None and not self.machine:
                    continue
                fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
                cpu_s = (int(fields[11]) + int(fields[12])) / CLK_TCK
            except (OSError, ValueError, IndexError):
                continue  # the process ended between listing and reading
            if name is None:
                others[pid] = cpu_s
                if pid not in self._comm:
                    try:
                        self._comm[pid] = Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode(
                            errors="replace").strip()[:80] or Path(f"/proc/{pid}/comm").read_text().strip()
                    except OSError:
                        self._comm[pid] = "?"
            else:
                snap[name] = cpu_s
        if self.machine:
            snap[MACHINE] = 0.5 * (before + machine_busy_s())
            self._others[len(self.samples)] = others
        return snap

    def _run(self) -> None:
        while not self._stop.is_set():
            self.samples.append((time.time(), self._snapshot()))
            time.sleep(self.period_s)

    def cpu_between(self, t0: float, t1: float) -> dict[str, float]:
        """CPU seconds each process used between wall times t0 and t1 (nearest samples); :data:`MACHINE`: the whole
        machine's busy CPU seconds in that time (from /proc/stat's ticks: others' processes included) and
        :data:`OTHERS`: those of every process not of this bench alive at both ends, when sampled (``machine``)."""
        i = min(range(len(self.samples)), key=lambda n: abs(self.samples[n][0] - t0))
        j = min(range(len(self.samples)), key=lambda n: abs(self.samples[n][0] - t1))
        a, b = self.samples[i][1], self.samples[j][1]
        out = {k: b[k] - a.get(k, 0.0) for k in b}
        if self.machine:  # every other process alive at both samples (one that came and went is not seen)
            oa, ob = self._others.get(i, {}), self._others.get(j, {})
            out[OTHERS] = sum(ob[pid] - oa[pid] for pid in ob.keys() & oa.keys())
        return out

    def busiest_others(self, t0: float, t1: float, n: int = 3) -> list[tuple[str, float]]:
        """The ``n`` other processes (pid and command line) that used the most CPU seconds between t0 and t1."""
        i = min(range(len(self.samples)), key=lambda m: abs(self.samples[m][0] - t0))
        j = min(range(len(self.samples)), key=lambda m: abs(self.samples[m][0] - t1))
        oa, ob = self._others.get(i, {}), self._others.get(j, {})
        used = sorted(((ob[pid] - oa[pid], pid) for pid in ob.keys() & oa.keys()), reverse=True)[:n]
        return [(f"{pid} {self._comm.get(pid, '?')}", round(cpu, 3)) for cpu, pid in used if cpu > 0]
