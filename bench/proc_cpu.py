"""CPU time per process of a bench's ROS nodes, sampled from /proc (shared by the bench scripts)."""

from __future__ import annotations

import os
import threading
import time
from pathlib import Path

CLK_TCK = os.sysconf("SC_CLK_TCK")


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

    def __init__(self, domain: str, period_s: float = 0.1):
        self.domain = domain.encode()
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

    def _snapshot(self) -> dict[str, float]:
        snap = {}
        for pid in os.listdir("/proc"):
            if not pid.isdigit():
                continue
            try:
                name = process_name(Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0"))
                if name is None:
                    continue
                if b"ROS_DOMAIN_ID=" + self.domain not in Path(f"/proc/{pid}/environ").read_bytes().split(b"\0"):
                    continue
                fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
                snap[name] = (int(fields[11]) + int(fields[12])) / CLK_TCK
            except (OSError, ValueError, IndexError):
                continue  # the process ended between listing and reading
        return snap

    def _run(self) -> None:
        while not self._stop.is_set():
            self.samples.append((time.time(), self._snapshot()))
            time.sleep(self.period_s)

    def cpu_between(self, t0: float, t1: float) -> dict[str, float]:
        """CPU seconds each process used between wall times t0 and t1 (nearest samples)."""
        a = min(self.samples, key=lambda s: abs(s[0] - t0))[1]
        b = min(self.samples, key=lambda s: abs(s[0] - t1))[1]
        return {k: b[k] - a.get(k, 0.0) for k in b}
