"""Console-script entry points of the nodes (``ros2 run <package> <executable>``), light enough to catch Ctrl-C.

A node module imports numpy, scipy, OpenCV and rclpy: one to three seconds before its ``main`` can install the
node's signal handling (:func:`vibro_ros.node_support.run_node`). A SIGINT or SIGTERM in that time (Ctrl-C right
after ``ros2 launch``, or launch shutting a run down) would raise KeyboardInterrupt in the middle of an import:
a traceback and exit code -2 ("process has died"). These entry points install :func:`stop_while_starting` first,
then import the node module and run its ``main``, which replaces the handler: a stop before the node exists is a
clean exit 0 with one line. This module imports nothing heavy (``vibro_ros/__init__`` imports nothing).

Why the table of node modules sits here, on the ground floor, and not as ``package.module:main`` in each setup.py
as the rclpy examples declare it: a console script ``vibro_dic.dic_tracker_node:main`` imports ``vibro_dic``'s
``__init__`` (the tracker, OpenCV, numba) before any of its code runs, and a package-local entry module
(``vibro_dic.entry``) would do the same. Only a package whose ``__init__`` is empty can hold the early handler,
and ``vibro_ros`` is the one every node package depends on. The table names the higher packages' modules as
strings (nothing of them is imported here, so no arrow points up the package graph), each package's setup.py
points its console scripts at the functions below, and tests/test_packaging.py and tests/test_launch_order.py
hold the table equal to the graph's node specs (vibro_bringup.graph_spec).
"""

from __future__ import annotations

import faulthandler
import importlib
import os
import signal
import sys

from vibro_model.threads import one_blas_thread

#: executable (``ros2 run`` name) -> node module with ``main()``; each package's setup.py points its console
#: scripts at the functions below
NODE_MODULES = {
    "frame_source": "vibro_dic.frame_source_node",
    "dic_tracker": "vibro_dic.dic_tracker_node",
    "accel_source": "vibro_fit.accel_source_node",
    "impact_detector": "vibro_fit.impact_detector_node",
    "trajectory_fitter": "vibro_fit.trajectory_fitter_node",
    "simulator": "vibro_sim.simulator_node",
    "discrepancy": "vibro_discrepancy.discrepancy_node",
    "recorder": "vibro_ros.recorder_node",
    "bag_source": "vibro_ros.bag_source_node",
    "foxglove_bridge": "vibro_foxglove.bridge_node",
}


_starting = ["vibro node"]  # the name the early-stop line gives (the node being started)


def stop_while_starting(signum: int, _frame) -> None:
    """Signal handler while a node starts: one line on stderr, exit code 0 at once (nothing to clean up yet)."""
    sys.stderr.write(f"{_starting[0]}: stopped by {signal.Signals(signum).name} while starting; exit code 0\n")
    sys.stderr.flush()
    os._exit(0)


def install_early_stop(name: str = "vibro node") -> None:
    """SIGINT and SIGTERM end the process cleanly (exit 0) until the node installs its own handlers."""
    _starting[0] = name
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, stop_while_starting)


#: The signal on which a node's process writes the Python stack of each of its threads to stderr (its log) and
#: goes on: ``kill -USR1 <pid>`` on a node that hangs; vibro graph sends it before it kills one
#: (vibro_bringup.supervisor).
STACK_DUMP_SIGNAL = signal.SIGUSR1


def install_stack_dump() -> None:
    """Have the process write every thread's Python stack to stderr on :data:`STACK_DUMP_SIGNAL`, and on a fatal
    signal (SIGSEGV, SIGABRT, ...) before it dies. Python's faulthandler writes from the C signal handler, so the
    stacks come also from a process whose main thread is blocked in a C call (a DDS wait, ``destroy_node``) that
    no Python signal handler would interrupt: once under load a trajectory_fitter never exited after its final
    outputs and ignored SIGINT until killed (a CI run, tests/test_isolation.py), and nothing said where it was."""
    faulthandler.enable(file=sys.stderr, all_threads=True)
    faulthandler.register(STACK_DUMP_SIGNAL, file=sys.stderr, all_threads=True, chain=False)


def exit_now(code) -> None:
    """End a node's process with ``code`` once its ``main()`` has returned: logs and stdio flushed, then
    ``os._exit``, without the interpreter's finalisation. The node has left the ROS graph by then (run_node's
    cleanup); what finalisation would still do is tear down DDS and library threads, which under load once hung:
    a trajectory_fitter alive 120 s after logging "left the ROS graph with exit code 0", killed by its supervisor
    with -9 (a loaded `make test`, tests/test_graph_faults.py)."""
    import logging

    if isinstance(code, str):   # sys.exit("message"): said on stderr, exit code 1, as the interpreter does
        sys.stderr.write(code + "\n")
        code = 1
    try:
        code = int(code or 0)
    except (TypeError, ValueError):
        code = 1
    try:
        logging.shutdown()
        sys.stdout.flush()
        sys.stderr.flush()
    finally:
        os._exit(code)


def prepare_node_process(name: str) -> None:
    """What a node's process does before it imports the node module (``ros2 run``'s entry points and vibro graph's
    vibro_bringup.child): a stop while starting is a clean exit (:func:`install_early_stop`), stacks on
    SIGUSR1 (:func:`install_stack_dump`), one BLAS thread (before numpy loads: a node's BLAS pool would spin beside
    seven other nodes), and the node's objects kept until ``os._exit`` (the process ends with :func:`exit_now`)."""
    install_early_stop(name)
    install_stack_dump()
    one_blas_thread()
    from vibro_ros.node_support import keep_node_objects_until_exit  # after the early stop: it loads rclpy

    keep_node_objects_until_exit()


def run(executable: str) -> int:
    """Start node ``executable``: early stop handling, then its module's ``main()``; the process ends with its exit
    code (:func:`exit_now`)."""
    prepare_node_process(executable)
    code = importlib.import_module(NODE_MODULES[executable]).main()
    exit_now(code)
    return code  # not reached


def frame_source() -> int:
    return run("frame_source")


def dic_tracker() -> int:
    return run("dic_tracker")


def accel_source() -> int:
    return run("accel_source")


def impact_detector() -> int:
    return run("impact_detector")


def trajectory_fitter() -> int:
    return run("trajectory_fitter")


def simulator() -> int:
    return run("simulator")


def discrepancy() -> int:
    return run("discrepancy")


def recorder() -> int:
    return run("recorder")


def bag_source() -> int:
    return run("bag_source")


def foxglove_bridge() -> int:
    return run("foxglove_bridge")
