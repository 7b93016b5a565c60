"""Start the nodes of graph_spec.launch_nodes the way ``ros2 launch`` does (launch is not installable here):
separate processes, the console scripts' mains, each node's parameters file and remappings."""

from __future__ import annotations

import ast
import random
import subprocess
import sys
import time
from pathlib import Path

import yaml

REPO = Path(__file__).resolve().parents[1]


def console_scripts() -> dict[tuple[str, str], str]:
    """(package, executable) -> "module:function" from every src/*/setup.py."""
    found = {}
    for setup in REPO.glob("src/*/setup.py"):
        tree = ast.parse(setup.read_text())
        for node in ast.walk(tree):
            if isinstance(node, ast.Constant) and isinstance(node.value, str) and " = " in node.value \
                    and ":" in node.value:
                exe, target = (x.strip() for x in node.value.split("="))
                found[(setup.parent.name, exe)] = target
    return found


def launch_command(n, params_file: Path) -> list[str]:
    """What ros2 launch runs for a launch_ros Node: the console script (here: its main, by the same import
    the generated script does), --ros-args, the node name, the parameters file (a dict's parameters are
    written under ``/**``) and the remappings."""
    module, func = console_scripts()[(n.spec.package, n.spec.executable)].split(":")
    cmd = [sys.executable, "-c", f"import sys; from {module} import {func}; sys.exit({func}())",
           "--ros-args", "-r", f"__node:={n.spec.name}", "--params-file", str(params_file)]
    for src, dst in n.remappings:
        cmd += ["-r", f"{src}:={dst}"]
    return cmd


def run_as_launch(nodes, folder: Path, env: dict[str, str], seed: int, timeout_s: float = 150.0) -> dict[str, int]:
    """Start ``nodes`` in shuffled order (a source first, the recorder last: the order vibro graph never
    uses) at random times within 2 s; wait until all have exited by themselves. Returns exit codes."""
    rng = random.Random(seed)
    order = list(nodes)
    rng.shuffle(order)
    sources = [n for n in order if n.spec.role == "source"]
    first = rng.choice(sources)
    order.remove(first)
    order.insert(0, first)
    sink = [n for n in order if n.spec.role == "sink"]
    for n in sink:
        order.remove(n)
        order.append(n)
    offsets = sorted(rng.uniform(0.0, 2.0) for _ in order)
    procs: dict[str, subprocess.Popen] = {}
    t0 = time.monotonic()
    for n, offset in zip(order, offsets):
        time.sleep(max(0.0, t0 + offset - time.monotonic()))
        params = folder / f"{n.spec.name}.params.yaml"
        params.write_text(yaml.safe_dump({"/**": {"ros__parameters": n.parameters}}))
        with (folder / f"{n.spec.name}.log").open("w") as log:
            procs[n.spec.name] = subprocess.Popen(launch_command(n, params), stdout=log, stderr=subprocess.STDOUT,
                                                  env=env)
    deadline = time.monotonic() + timeout_s
    try:
        while time.monotonic() < deadline and any(p.poll() is None for p in procs.values()):
            time.sleep(0.1)
    finally:
        for p in procs.values():
            if p.poll() is None:
                p.kill()
                p.wait()
    return {name: p.returncode for name, p in procs.items()}
