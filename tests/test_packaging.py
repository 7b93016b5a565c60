"""ROS packaging conventions: package.xml format 3, ros2 run entry points that exist, one graph definition."""

from __future__ import annotations

import ast
import importlib
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from vibro_bringup.graph_spec import NODES

SRC = Path(__file__).resolve().parents[1] / "src"
PYTHON_PACKAGES = ["vibro_io", "vibro_ros", "vibro_eval", "vibro_dic", "vibro_fit", "vibro_sim", "vibro_bringup"]


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
    for spec in NODES:
        scripts = console_scripts(spec.package)
        assert scripts.get(spec.executable) == f"{spec.module}:main", spec


def test_launch_file_uses_the_shared_graph_definition() -> None:
    text = (SRC / "vibro_bringup" / "launch" / "vibro.launch.py").read_text()
    tree = ast.parse(text)
    imported = {(n.module, a.name) for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) for a in n.names}
    # launch_nodes: the node table's nodes with node_parameters' parameters (tests/test_launch_order.py
    # starts what it returns and compares the run with vibro graph)
    assert ("vibro_bringup.graph_spec", "launch_nodes") in imported
