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

from vibro_model.threads import one_blas_thread
from vibro_ros.entry import exit_now, install_early_stop


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
    install_early_stop(module.rsplit(".", 1)[-1])  # a stop while the node module imports: exit 0, no traceback
    one_blas_thread()            # before the node module loads numpy (vibro_model.threads)
    from vibro_ros.node_support import keep_node_objects_until_exit  # after the early stop: it loads rclpy

    keep_node_objects_until_exit()  # the process ends with os._exit: no destructors on a shut-down context
    sys.argv = [module, *sys.argv[2:]]
    try:
        runpy.run_module(module, run_name="__main__", alter_sys=True)
        code = 0
    except SystemExit as done:   # the node module's sys.exit(main()): its exit code
        code = done.code
    exit_now(code)               # without the interpreter's finalisation (vibro_ros.entry.exit_now)


if __name__ == "__main__":
    main()
