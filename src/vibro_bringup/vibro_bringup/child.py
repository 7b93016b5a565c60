"""``python -m vibro_bringup.child MODULE ARGS...``: run a node module that dies with its parent.

The graph runner starts every node through this wrapper, which asks Linux to send the
node SIGTERM when the runner dies (PR_SET_PDEATHSIG), so a killed runner leaves no
orphaned nodes on the DDS domain. (Done here rather than in a preexec_fn, which is unsafe
in the runner's multi-threaded process.)
"""

from __future__ import annotations

import ctypes
import os
import runpy
import signal
import sys

from vibro_ros.entry import exit_now, prepare_node_process


def main() -> None:
    if len(sys.argv) < 2:
        sys.exit("usage: python -m vibro_bringup.child MODULE [ARGS...]")
    try:
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG
        if os.getppid() == 1:  # the parent died before prctl took effect
            sys.exit(0)
    except OSError:
        pass

    module = sys.argv[1]
    prepare_node_process(module.rsplit(".", 1)[-1])  # as `ros2 run` starts a node: early stop, stacks on SIGUSR1
    sys.argv = [module, *sys.argv[2:]]
    try:
        runpy.run_module(module, run_name="__main__", alter_sys=True)
        code = 0
    except SystemExit as done:   # the node module's sys.exit(main()): its exit code
        code = done.code
    exit_now(code)               # without the interpreter's finalisation (vibro_ros.entry.exit_now)


if __name__ == "__main__":
    main()
