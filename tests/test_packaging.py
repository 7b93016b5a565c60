"""ROS packaging conventions: package.xml format 3, ros2 run entry points that exist, one graph definition."""

from __future__ import annotations

import ast
import importlib
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from vibro_bringup.graph_spec import BAG_SOURCE, NODES

SRC = Path(__file__).resolve().parents[1] / "src"
PYTHON_PACKAGES = ["vibro_model", "vibro_io", "vibro_ros", "vibro_eval", "vibro_dic", "vibro_fit", "vibro_sim",
                   "vibro_discrepancy", "vibro_foxglove", "vibro_app", "vibro_bringup"]


def console_scripts(pkg: str) -> dict[str, str]:
    """name -> 'module:function' from the package's setup.py (parsed, not executed)."""
    tree = ast.parse((SRC / pkg / "setup.py").read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.Dict):
            for key, value in zip(node.keys, node.values):
                if isinstance(key, ast.Constant) and key.value == "console_scripts":
                    entries = [ast.literal_eval(e) for e in value.elts]
                    return dict(e.replace(" ", "").split("=", 1) for e in entries)
    return {}


@pytest.mark.parametrize("pkg", ["vibro_msgs", *PYTHON_PACKAGES])
def test_package_xml_is_format_3_and_named_like_its_folder(pkg: str) -> None:
    root = ET.parse(SRC / pkg / "package.xml").getroot()
    assert root.tag == "package" and root.get("format") == "3"
    assert root.findtext("name") == pkg
    assert "@" in root.find("maintainer").get("email")  # catkin_pkg refuses a package without a valid e-mail
    build_type = root.find("export/build_type").text
    assert build_type == ("ament_cmake" if pkg == "vibro_msgs" else "ament_python")


@pytest.mark.parametrize("pkg", PYTHON_PACKAGES)
def test_ament_python_layout_and_entry_points(pkg: str) -> None:
    assert (SRC / pkg / "resource" / pkg).is_file()
    cfg = (SRC / pkg / "setup.cfg").read_text()
    assert f"script_dir=$base/lib/{pkg}" in cfg and f"install_scripts=$base/lib/{pkg}" in cfg
    for name, target in console_scripts(pkg).items():
        module, func = target.split(":")
        assert callable(getattr(importlib.import_module(module), func)), f"{pkg} {name} -> {target}"


def test_every_graph_node_is_a_ros2_run_entry_point() -> None:
    """Every node of the table is a console script of its package, through the light entry module
    (vibro_ros.entry: early Ctrl-C handling) that starts the table's node module."""
    from vibro_ros.entry import NODE_MODULES

    for spec in (*NODES, BAG_SOURCE):
        scripts = console_scripts(spec.package)
        assert scripts.get(spec.executable) == f"vibro_ros.entry:{spec.executable}", spec
        assert NODE_MODULES[spec.executable] == spec.module, spec
        assert callable(getattr(importlib.import_module(spec.module), "main")), spec


def test_launch_file_uses_the_shared_graph_definition() -> None:
    text = (SRC / "vibro_bringup" / "launch" / "vibro.launch.py").read_text()
    tree = ast.parse(text)
    imported = {(n.module, a.name) for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) for a in n.names}
    # launch_nodes: the node table's nodes with node_parameters' parameters (tests/test_launch_order.py
    # starts what it returns and compares the run with vibro graph)
    assert ("vibro_bringup.graph_spec", "launch_nodes") in imported


# --- #16.7: every runtime import is declared in package.xml (what `rosdep install` brings) ---------------

#: Third-party import name -> rosdep key (keys checked in ros/rosdistro rosdep/python.yaml).
ROSDEP_KEYS = {"numpy": "python3-numpy", "scipy": "python3-scipy", "cv2": "python3-opencv",
               "matplotlib": "python3-matplotlib", "tqdm": "python3-tqdm", "yaml": "python3-yaml",
               "numba": "python3-numba"}
#: Import name -> pip distribution, for packages rosdep has no key for: requirements.txt pins them and
#: README lists them under "Python dependencies".
PIP_ONLY = {"mcap": "mcap", "rosbags": "rosbags", "pysindy": "pysindy",
            "nptdms": "nptdms", "pyMRAW": "pymraw", "pycine": "pycine", "foxglove": "foxglove-sdk",
            "distributed": "distributed", "dask": "dask"}
#: ROS packages imported under their own name (the rosdep key is the package name).
ROS_PACKAGES = {"rclpy", "rcl_interfaces", "std_msgs", "sensor_msgs", "diagnostic_msgs", "launch", "launch_ros",
                "ament_index_python", "vibro_msgs", *PYTHON_PACKAGES}
#: The evaluation harness is a dev package: no runtime package may need it or its pip-only baseline.
DEV_PACKAGES = {"vibro_eval"}
DEV_ONLY_IMPORTS = {"vibro_eval", "pysindy"}


def _sources(pkg: str) -> list[Path]:
    files = sorted((SRC / pkg / pkg).rglob("*.py"))
    return files + sorted((SRC / pkg / "launch").glob("*.py")) if (SRC / pkg / "launch").is_dir() else files


def imported_top_levels(pkg: str) -> dict[str, str]:
    """Top-level name of every absolute import in the package's modules and launch files -> first file:line."""
    import sys

    found: dict[str, str] = {}
    for path in _sources(pkg):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names = [node.module]
            else:
                continue
            for name in names:
                top = name.split(".")[0]
                if top not in sys.stdlib_module_names and top != pkg and top != "__future__":
                    found.setdefault(top, f"{path.relative_to(SRC)}:{node.lineno}")
    return found


def exec_depends(pkg: str) -> set[str]:
    root = ET.parse(SRC / pkg / "package.xml").getroot()
    return {e.text.strip() for tag in ("exec_depend", "depend") for e in root.findall(tag)}


def rosdep_key(import_name: str) -> str | None:
    if import_name in ROS_PACKAGES:
        return import_name
    return ROSDEP_KEYS.get(import_name)


def test_import_scanner_sees_lazy_imports_inside_functions() -> None:
    # graph_spec imports cv2 only inside write_reference_frame: the scanner must still see it
    assert "cv2" in imported_top_levels("vibro_bringup")


@pytest.mark.parametrize("pkg", PYTHON_PACKAGES)
def test_every_import_of_a_package_is_declared_in_its_package_xml(pkg: str) -> None:
    declared = exec_depends(pkg)
    problems = []
    for name, where in sorted(imported_top_levels(pkg).items()):
        if name in PIP_ONLY:
            continue  # checked below: pinned in requirements.txt and listed in README
        key = rosdep_key(name)
        if key is None:
            problems.append(f"{where}: import {name}: no rosdep key known; add it to ROSDEP_KEYS or PIP_ONLY")
        elif key not in declared:
            problems.append(f"{where}: import {name}: <exec_depend>{key}</exec_depend> missing in {pkg}/package.xml")
    assert not problems, "\n".join(problems)


@pytest.mark.parametrize("pkg", PYTHON_PACKAGES)
def test_no_declared_python_dependency_is_stale(pkg: str) -> None:
    imported_keys = {rosdep_key(n) for n in imported_top_levels(pkg)}
    stale = {k for k in exec_depends(pkg) if k.startswith("python3-") and k not in imported_keys}
    assert not stale, f"{pkg}/package.xml declares {sorted(stale)} but no module of {pkg} imports them"


def test_pip_only_dependencies_are_pinned_and_documented() -> None:
    repo = SRC.parent
    pinned = {line.split("==")[0].strip().lower()
              for req in ("requirements.txt", "requirements-nodeps.txt")
              for line in (repo / req).read_text().splitlines()
              if "==" in line and not line.lstrip().startswith("#")}
    readme = (repo / "README.md").read_text(encoding="utf-8")
    used = {name for pkg in PYTHON_PACKAGES for name in imported_top_levels(pkg) if name in PIP_ONLY}
    assert used == set(PIP_ONLY), f"PIP_ONLY lists packages nothing imports: {set(PIP_ONLY) - used}"
    for name in sorted(used):
        assert PIP_ONLY[name] in pinned, f"pip-only {PIP_ONLY[name]} not pinned in requirements.txt"
        assert f"`{PIP_ONLY[name]}`" in readme, f"pip-only {PIP_ONLY[name]} not listed in README.md"


@pytest.mark.parametrize("pkg", sorted(set(PYTHON_PACKAGES) - DEV_PACKAGES))
def test_runtime_packages_do_not_need_the_evaluation_harness(pkg: str) -> None:
    assert not exec_depends(pkg) & DEV_PACKAGES, f"{pkg}/package.xml depends on a dev package"
    bad = {n: w for n, w in imported_top_levels(pkg).items() if n in DEV_ONLY_IMPORTS}
    assert not bad, f"{pkg} imports dev-only packages: {bad}"


def test_recorder_message_packages_are_declared() -> None:
    # the recorder imports the message class of every topic by name (importlib), invisible to the scanner
    from vibro_ros import topics

    needed = {t.msg_type.split("/")[0] for t in topics.ALL_TOPICS}
    assert needed <= exec_depends("vibro_ros"), needed - exec_depends("vibro_ros")


def test_vibro_cli_works_without_the_evaluation_harness(monkeypatch: pytest.MonkeyPatch) -> None:
    """A runtime install (no vibro_eval) still has every other subcommand; only `vibro prove` is absent."""
    import sys

    from vibro_app import cli

    for name in [m for m in sys.modules if m == "vibro_eval" or m.startswith("vibro_eval.")]:
        monkeypatch.delitem(sys.modules, name)
    monkeypatch.setitem(sys.modules, "vibro_eval", None)  # import vibro_eval -> ModuleNotFoundError
    commands = cli.build_parser()._subparsers._group_actions[0].choices
    assert "prove" not in commands and {"graph", "analyze", "results", "replay"} <= set(commands)


def test_a_node_refuses_an_unknown_argument_with_one_line() -> None:
    """`impact_detector --threshold 3` (meant as a parameter) must not start a node that ignores it."""
    import subprocess
    import sys

    res = subprocess.run([sys.executable, "-m", "vibro_fit.impact_detector_node", "--threshold", "3"],
                         capture_output=True, text=True, timeout=60)
    assert res.returncode == 2 and "Traceback" not in res.stderr
    assert res.stderr.strip().splitlines() == [
        "vibro_fit.impact_detector_node: error: unknown argument(s) --threshold 3 (ROS arguments go after "
        "--ros-args; see --help)"]
