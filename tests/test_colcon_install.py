"""#16.2: what a lab PC gets from `colcon build`: the console scripts `ros2 run` starts, and the
installed params file.

The runtime ament_python packages are built once per test session with colcon into a temporary
workspace (vibro_eval, the dev-only evaluation harness, is left out as a runtime install would; the
interface package vibro_msgs comes from the project's install/, built by scripts/build_msgs.sh, since
its rosidl build through colcon takes minutes here). Then every node's installed script runs as
`ros2 run` would run it: `install/<pkg>/lib/<pkg>/<node>` after `. install/setup.sh`.
"""

from __future__ import annotations

import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml
from ros_probe import Probe

from vibro_bringup.graph_spec import BAG_SOURCE, NODES, NodeSpec, params_file_key

SRC = Path(__file__).resolve().parents[1] / "src"
RUNTIME_PACKAGES = ["vibro_model", "vibro_io", "vibro_ros", "vibro_dic", "vibro_fit", "vibro_sim", "vibro_discrepancy",
                    "vibro_foxglove", "vibro_app", "vibro_bringup"]
BUILD_TIMEOUT_S = 400


@pytest.fixture(scope="module")
def colcon_install(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """`colcon build` of the runtime packages into a temporary workspace; its install/ folder."""
    colcon = shutil.which("colcon", path=str(Path(sys.executable).parent)) or shutil.which("colcon")
    assert colcon, "colcon not installed: `make setup` installs it from requirements.txt"
    ws = tmp_path_factory.mktemp("colcon_ws")
    cmd = [colcon, "--log-base", str(ws / "log"), "build", "--base-paths", *(str(SRC / p) for p in RUNTIME_PACKAGES),
           "--build-base", str(ws / "build"), "--install-base", str(ws / "install")]
    start = time.monotonic()
    res = subprocess.run(cmd, cwd=ws, capture_output=True, text=True, timeout=BUILD_TIMEOUT_S)
    elapsed = time.monotonic() - start
    assert res.returncode == 0, (f"colcon build failed after {elapsed:.0f} s:\n{res.stdout[-4000:]}\n"
                                 f"{res.stderr[-4000:]}")
    print(f"\ncolcon build of {len(RUNTIME_PACKAGES)} packages: {elapsed:.1f} s", file=sys.stderr)
    return ws / "install"


def installed(install: Path, *argv: str | Path) -> list[str]:
    """A command run as on a lab PC after `. install/setup.sh`."""
    return ["sh", "-c", '. "$1/setup.sh" && shift && exec "$@"', "sh", str(install), *map(str, argv)]


def script(install: Path, spec: NodeSpec) -> Path:
    """The file `ros2 run <package> <executable>` executes."""
    return install / spec.package / "lib" / spec.package / spec.executable


def test_the_readmes_setup_line_works_in_bash(colcon_install: Path) -> None:
    """README.md and docs/install.md say ``source install/setup.bash`` after ``colcon build``: that file exists
    (colcon-bash, in requirements.txt) and, sourced by bash exactly so, puts the installed packages first."""
    assert (colcon_install / "setup.bash").is_file()
    res = subprocess.run(["bash", "-c", f"cd {colcon_install.parent} && source install/setup.bash && "
                          f"{sys.executable} -c 'import vibro_app; print(vibro_app.__file__)'"],
                         capture_output=True, text=True, timeout=60)
    assert res.returncode == 0, res.stderr
    assert res.stdout.strip().startswith(str(colcon_install)), res.stdout


def test_installed_console_scripts_print_usage(colcon_install: Path) -> None:
    specs = [*NODES, BAG_SOURCE]
    config = yaml.safe_load((colcon_install / "vibro_bringup" / "share" / "vibro_bringup" / "config" /
                             "vibro.yaml").read_text())
    procs = {spec: subprocess.Popen(installed(colcon_install, script(colcon_install, spec), "--help"),
                                    stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for spec in specs}
    where = subprocess.run(installed(colcon_install, sys.executable, "-c",
                                     "import vibro_dic.dic_tracker_node as m; print(m.__file__)"),
                           capture_output=True, text=True, timeout=60)
    cli = subprocess.run(installed(colcon_install, colcon_install / "vibro_app" / "lib" / "vibro_app" / "vibro",
                                   "--help"), capture_output=True, text=True, timeout=60)
    for spec, proc in procs.items():
        out, err = proc.communicate(timeout=120)
        assert proc.returncode == 0, f"{spec.executable} --help: exit {proc.returncode}\n{err}"
        assert out.startswith(f"usage: ros2 run {spec.package} {spec.executable} "), out[:200]
        declared = set(re.findall(r"^  (\w+) +\w+(?:\[\])?, default ", out, flags=re.M))
        lab_defaults = set(config.get(params_file_key(spec.name), {}).get("ros__parameters", {}))
        # every value the lab defaults file sets names a parameter the node declares (else it is ignored)
        assert lab_defaults <= declared, f"{spec.name}: {lab_defaults - declared} in vibro.yaml, not declared"
        reads, writes = out.split("reads (subscribes to):")[1].split("writes (publishes):")
        assert "/diagnostics" in writes and "vibro/" in reads + writes, out
    # the modules come from the colcon install, not from the source tree
    assert where.returncode == 0 and Path(where.stdout.strip()).is_relative_to(colcon_install), where
    assert cli.returncode == 0 and "graph" in cli.stdout, cli.stderr


def test_installed_nodes_run_with_the_installed_params_file_under_a_namespace(
        colcon_install: Path, tiny_recording: Path, ros_domain: str) -> None:
    from diagnostic_msgs.msg import DiagnosticArray

    from vibro_dic.frame_source_node import FrameSource
    from vibro_ros.node_help import node_interface

    params_file = colcon_install / "vibro_bringup" / "share" / "vibro_bringup" / "config" / "vibro.yaml"
    lab = yaml.safe_load(params_file.read_text())[params_file_key("frame_source")]["ros__parameters"]
    code_default = {p.name: p.default for p in node_interface(FrameSource).parameters}
    assert lab["linger_s"] != code_default["linger_s"]  # so the file's effect shows
    by_name = {spec.name: spec for spec in NODES}
    ros_args = ["--ros-args", "-r", "__ns:=/lab1", "--params-file", params_file]
    procs = [subprocess.Popen(installed(colcon_install, script(colcon_install, by_name["dic_tracker"]), *ros_args,
                                        "-p", f"rig_file:={tiny_recording / 'rig.yaml'}"),
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True),
             # the source waits for its declared readers, tracker + recorder (as in a lab graph): no recorder
             # runs here, so it only idles, its parameter service up
             subprocess.Popen(installed(colcon_install, script(colcon_install, by_name["frame_source"]), *ros_args,
                                        "-p", f"recording:={tiny_recording}", "-p", "readers:=[dic_tracker,recorder]"),
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)]
    try:
        with Probe() as probe:
            diagnostics = probe.subscribe(DiagnosticArray, "/diagnostics")
            wanted = {"/lab1/dic_tracker", "/lab1/frame_source"}
            up = probe.spin_until(lambda: wanted <= {s.name for m in diagnostics for s in m.status}, 90)
            source_params = probe.get_parameters("/lab1/frame_source", list(lab) + ["recording"]) if up else {}
    finally:
        for proc in procs:
            if proc.poll() is None:
                proc.send_signal(signal.SIGINT)
        errs = [proc.communicate(timeout=30)[1] for proc in procs]
    assert up, "installed nodes never reported on /diagnostics:\n" + "\n".join(errs)
    assert source_params == {**lab, "recording": str(tiny_recording)}
    for proc, err in zip(procs, errs):
        assert proc.returncode == 0 and "Traceback" not in err, err


def test_the_installed_vibro_ros_carries_its_fast_dds_profile(colcon_install: Path) -> None:
    # run_node points Fast DDS at vibro_ros/fastdds_profile.xml beside the module: it must be installed too
    found = list((colcon_install / "vibro_ros").rglob("vibro_ros/fastdds_profile.xml"))
    assert found, "fastdds_profile.xml missing from the colcon install of vibro_ros"
    assert found[0].read_text() == (SRC / "vibro_ros" / "vibro_ros" / "fastdds_profile.xml").read_text()
