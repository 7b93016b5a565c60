"""One BLAS thread per vibro process (vibro_model.threads): the node entry points and the ``vibro`` command set it
before numpy loads, and a value the caller set wins. Checked in fresh processes whose environment has none of the
variables (the suite's own conftest sets them for everything it starts: removed here), by the thread count
OpenBLAS reports once loaded."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from vibro_model.threads import THREAD_VARIABLES

threadpoolctl = pytest.importorskip("threadpoolctl")

PROBE = """
import json, os, sys
import numpy, threadpoolctl
pools = [p["num_threads"] for p in threadpoolctl.threadpool_info() if p.get("internal_api") == "openblas"]
print(json.dumps({"env": {k: os.environ.get(k) for k in %r}, "openblas": pools}))
"""


def _bare_env(**extra: str) -> dict:
    env = {k: v for k, v in os.environ.items() if k not in THREAD_VARIABLES}
    env.update(extra)
    return env


def _run(code: str, env: dict) -> dict:
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, env=env)
    assert res.returncode == 0, res.stderr
    return json.loads(res.stdout.strip().splitlines()[-1])


@pytest.mark.skipif((os.cpu_count() or 1) < 2, reason="one core: OpenBLAS starts one thread anyway")
def test_a_plain_process_has_a_pool_of_several_and_a_vibro_process_one(tmp_path) -> None:
    probe = PROBE % (THREAD_VARIABLES,)
    plain = _run(probe, _bare_env())
    assert plain["openblas"] and plain["openblas"][0] > 1      # what the machine gives without vibro
    cli = _run("import vibro_app.cli\n" + probe, _bare_env())
    assert cli["openblas"] == [1] and set(cli["env"].values()) == {"1"}
    # a node: its entry point runs the node module's main() (here a probe module) after setting them
    (tmp_path / "probe_node.py").write_text("def main():\n" + "".join(f"    {line}\n" for line in
                                                                         probe.strip().splitlines()) + "    return 0\n")
    node = _run("import vibro_ros.entry as e\ne.NODE_MODULES['probe'] = 'probe_node'\ne.run('probe')",
                _bare_env(PYTHONPATH=f"{tmp_path}{os.pathsep}{os.environ.get('PYTHONPATH', '')}"))
    assert node["openblas"] == [1]
    # the caller's own value wins
    mine = _run("import vibro_app.cli\n" + probe, _bare_env(OPENBLAS_NUM_THREADS="2"))
    assert mine["openblas"] == [2] and mine["env"]["OPENBLAS_NUM_THREADS"] == "2"
