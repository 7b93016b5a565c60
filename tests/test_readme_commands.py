"""Every command README.md (and docs/commands.md) shows works as written (issue #29), checked in a cheap form:
each ``./vibro`` subcommand exists (``--help`` exits 0) with the options shown, each ``make`` target exists
(``make -n``), the lab-PC install pins are requirements.txt's, each ``ros2 run`` node is a console script of its
package whose ``--help`` works, each ``ros2 launch`` argument is declared by the launch file; the benchmark
commands docs/benchmarks.md and the bench scripts' docstrings show start as written (``--help``) with the
environment the node-graph benchmarks need. Nothing here runs a benchmark, a build or an analysis."""

from __future__ import annotations

import ast
import functools
import os
import re
import shlex
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: the environment a user has in a fresh shell: no scripts/env.sh sourced, no venv activated, nothing the ROS
#: wheels' start-up left (e.g. its _ROS_WHEELS_BOOTSTRAP_COMPLETE marker)
BARE_ENV = {k: os.environ[k] for k in ("HOME", "USER", "LANG", "LC_ALL", "TMPDIR", "TERM") if k in os.environ}
BARE_ENV["PATH"] = os.pathsep.join(p for p in os.environ.get("PATH", "/usr/bin:/bin").split(os.pathsep)
                                   if not p.startswith(str(ROOT)))


def fenced_commands(path: Path) -> list[str]:
    """The commands of a Markdown file's ```bash blocks (and its 4-space indented code lines): one per line,
    comments dropped, '&&' chains split."""
    commands, in_bash = [], False
    for line in path.read_text(encoding="utf-8").splitlines():
        if line.startswith("```"):
            in_bash = not in_bash and line.strip() in ("```bash", "```sh", "```console")
            continue
        if not in_bash and not (line.startswith("    ") and line.strip().startswith("scripts/py ")):
            continue
        code = re.sub(r"(^|\s)#.*$", "", line).strip()  # '# comment' (none of the commands quotes a '#')
        commands += [c.strip() for c in code.split("&&") if c.strip()]
    return commands


def run(args: list[str], env: dict | None = None, timeout: float = 60) -> subprocess.CompletedProcess:
    return subprocess.run(args, cwd=ROOT, capture_output=True, text=True, timeout=timeout, env=env or BARE_ENV)


@functools.cache
def help_of(*args: str) -> subprocess.CompletedProcess:
    """``run(args)`` of a ``--help`` line in the bare environment, once per test process: README.md,
    docs/commands.md and the bench docstrings show several lines of one command (``vibro synth`` twice,
    bench/bench_live.py five times); each line's options are checked against the one help text."""
    return run(list(args))


def requirement_pins() -> dict[str, str]:
    pins = {}
    for name in ("requirements.txt", "requirements-nodeps.txt"):
        for line in (ROOT / name).read_text().splitlines():
            m = re.match(r"\s*([A-Za-z0-9_.-]+)==([^\s;#]+)", line)
            if m:
                pins[m[1].lower().replace("_", "-")] = m[2]
    return pins


def console_scripts(package: str) -> dict[str, str]:
    """name -> 'module:function' of a package's setup.py entry points."""
    text = (ROOT / "src" / package / "setup.py").read_text()
    return dict(re.findall(r"[\"']([\w-]+)\s*=\s*([\w.]+:\w+)[\"']", text))


def launch_arguments(launch_file: Path) -> set[str]:
    """The names a launch file declares with DeclareLaunchArgument("name", ...) (read, not imported)."""
    names = set()
    for node in ast.walk(ast.parse(launch_file.read_text())):
        if isinstance(node, ast.Call) and getattr(node.func, "id", getattr(node.func, "attr", "")) == \
                "DeclareLaunchArgument" and node.args and isinstance(node.args[0], ast.Constant):
            names.add(node.args[0].value)
    return names


def subcommands(helptext: str) -> set[str]:
    """The subcommands an argparse help text lists: the rows under its ``COMMAND`` (``BAG_COMMAND``) positional."""
    block = re.search(r"positional arguments:\n  [A-Z_]*COMMAND\n((?:    .*\n|\s{10,}.*\n)+)", helptext)
    return set(re.findall(r"^    (\w[\w-]*)", block[1], re.M)) if block else set()


def vibro_help() -> subprocess.CompletedProcess:
    return help_of("./vibro", "--help")


def check_vibro(words: list[str]) -> None:
    top = vibro_help()
    assert top.returncode == 0, top.stderr
    if words == ["--help"]:
        return
    cmd = [words[0]]
    assert cmd[0] in subcommands(top.stdout), f"./vibro {cmd[0]}: not a subcommand ({top.stdout[:300]})"
    res = help_of("./vibro", *cmd, "--help")
    assert res.returncode == 0, f"./vibro {cmd[0]} --help: {res.stderr}"
    nested = subcommands(res.stdout)
    if nested:  # e.g. `vibro bag reindex`
        assert len(words) > 1 and words[1] in nested, f"./vibro {' '.join(words)}: {res.stdout[:300]}"
        sub = help_of("./vibro", cmd[0], words[1], "--help")
        assert sub.returncode == 0, sub.stderr
    # the options the line shows are the command's own
    shown = {w.split("=")[0] for w in words if w.startswith("--")}
    helptext = sub.stdout if nested else res.stdout
    assert all(opt in helptext for opt in shown - {"--help"}), (words, shown)


def check_make(target: str) -> None:
    res = run(["make", "-n", target])
    assert res.returncode == 0, f"make -n {target}: {res.stderr}"


def check_ros2_run(package: str, executable: str, args: list[str]) -> None:
    scripts = console_scripts(package)
    assert executable in scripts, f"ros2 run {package} {executable}: not a console script of {package}"
    module, func = scripts[executable].split(":")
    code = f"import sys; sys.argv = [{executable!r}, '--help']; from {module} import {func}; sys.exit({func}())"
    res = run([str(ROOT / "scripts" / "py"), "-c", code])
    assert res.returncode == 0 and "usage" in res.stdout.lower(), (executable, res.stdout[-500:], res.stderr[-500:])
    for name in (a.split(":=")[0] for k, a in enumerate(args) if k and args[k - 1] == "-p"):
        assert re.search(rf"\b{re.escape(name)}\b", res.stdout), f"{executable}: no parameter {name}"


def check_command(command: str) -> str:
    """Check one README command; returns how it was checked."""
    words = shlex.split(command)
    check = LINE_CHECKS.get(words[0])
    if check is not None:
        return check(command, words)
    if re.fullmatch(r"[A-Z_]+=\S+", command):  # PARAMS=install/<pkg>/share/<pkg>/config/<file>
        return _check_config_assignment(command)
    raise AssertionError(f"a README command this test does not know how to check: {command!r}")


def _check_vibro_line(command: str, words: list[str]) -> str:
    check_vibro(words[1:])
    return "vibro --help"


def _check_make_line(command: str, words: list[str]) -> str:
    for target in words[1:]:
        check_make(target)
    return "make -n"


def _check_source_line(command: str, words: list[str]) -> str:
    """The lab PC's ROS, and colcon's install/ after `colcon build`."""
    assert words[1] in ("/opt/ros/jazzy/setup.bash", "install/setup.bash"), command
    return "lab PC only"


def _check_cd_line(command: str, words: list[str]) -> str:
    assert words[1] == "vibro", command  # the clone's folder
    return "clone folder"


def _check_rosdep_line(command: str, words: list[str]) -> str:
    assert words[1] == "install" and "--from-paths" in words, command
    paths = words[words.index("--from-paths") + 1]
    assert list((ROOT / paths).glob("*/package.xml")), f"{paths}: no package.xml"
    return "package.xml files present"


def _check_pip_line(command: str, words: list[str]) -> str:
    pins = requirement_pins()
    for w in words[2:]:
        if "==" in w:
            name, version = w.split("==")
            assert pins.get(name.lower().replace("_", "-")) == version, f"{w}: requirements pin {pins.get(name)}"
    return "pins = requirements"


def _check_colcon_line(command: str, words: list[str]) -> str:
    res = run([str(ROOT / ".venv" / "bin" / "colcon"), *words[1:2], "--help"])
    assert res.returncode == 0, res.stderr
    for w in words[2:]:
        assert w.split("=")[0] in res.stdout, f"colcon {words[1]}: no option {w}"
    return "colcon --help"


def _check_config_assignment(command: str) -> str:
    """PARAMS=install/<pkg>/share/<pkg>/config/<file>: a config file the package installs."""
    value = command.split("=", 1)[1]
    m = re.fullmatch(r"install/(\w+)/share/\1/config/([\w.-]+)", value)
    assert m, command
    assert (ROOT / "src" / m[1] / "config" / m[2]).is_file()
    assert 'share/' + m[1] + '/config", glob("config/*.yaml")' in (ROOT / "src" / m[1] / "setup.py").read_text()
    return "installed config file"


def _check_ros2_line(command: str, words: list[str]) -> str:
    if words[1] == "run":
        check_ros2_run(words[2], words[3], words[4:])
        return "node --help"
    if words[1] == "launch":
        launch_file = ROOT / "src" / words[2] / "launch" / words[3]
        assert launch_file.is_file(), launch_file
        declared = launch_arguments(launch_file)
        for w in words[4:]:
            assert w.split(":=")[0] in declared, f"{w}: not an argument of {words[3]} ({sorted(declared)})"
        return "launch arguments declared"
    if words[1:3] == ["topic", "echo"]:
        check_topic_echo(words[3], words[4:])
        return "topic and QoS = topics.py"
    raise AssertionError(f"a README command this test does not know how to check: {command!r}")


def _check_bench_line(command: str, words: list[str]) -> str:
    check_bench(words)
    return "bench --help"


#: how each README command is checked, by its first word
LINE_CHECKS = {"./vibro": _check_vibro_line, "make": _check_make_line, "source": _check_source_line,
               "cd": _check_cd_line, "rosdep": _check_rosdep_line, "pip": _check_pip_line,
               "colcon": _check_colcon_line, "ros2": _check_ros2_line, "scripts/py": _check_bench_line}


def check_topic_echo(topic: str, options: list[str]) -> None:
    """A vibro topic, echoed with QoS its publishers' profile serves whole: same reliability and durability,
    at least its depth (a shallower or volatile echo drops messages, issue #25)."""
    from vibro_ros import topics as T
    from vibro_ros.node_support import RESULTS_QOS, STREAM_QOS, history_qos

    spec = next((t for t in T.ALL_TOPICS if topic == t.name or topic.endswith("/" + t.name)), None)
    assert spec is not None, f"{topic}: not a vibro topic"
    profile = {"results": RESULTS_QOS, "stream": STREAM_QOS, "history": history_qos()}[spec.qos]
    given = dict(zip(options[::2], options[1::2]))
    assert given.get("--qos-reliability") == profile.reliability.name.lower(), (topic, given)
    assert given.get("--qos-durability") == profile.durability.name.lower(), (topic, given)
    assert int(given.get("--qos-depth", 0)) >= profile.depth, (topic, given)


def check_bench(words: list[str]) -> None:
    script = ROOT / words[1]
    assert script.is_file(), script
    # never run a benchmark: its main() must parse its options (--help exits before any work)
    assert ".parse_args(" in script.read_text(), f"{script.name}: no argparse, --help would run it"
    res = help_of(f"./{words[0]}", words[1], "--help")
    assert res.returncode == 0 and res.stdout.startswith("usage:"), (words, res.stderr[-800:])
    for opt in re.findall(r"--[\w-]+", " ".join(words[2:])):
        assert opt in res.stdout, f"{script.name}: no option {opt}"


README_COMMANDS = fenced_commands(ROOT / "README.md")
#: docs/commands.md repeats the README's list with a few more; each distinct command checked once
COMMANDS = list(dict.fromkeys(README_COMMANDS + fenced_commands(ROOT / "docs" / "commands.md")))


def test_the_readme_shows_commands():
    heads = {shlex.split(c)[0] for c in README_COMMANDS}
    assert {"./vibro", "make", "pip", "ros2"} <= heads and len(README_COMMANDS) > 20


@pytest.mark.parametrize("command", COMMANDS)
def test_readme_command(command):
    check_command(command)


def bench_commands() -> list[str]:
    """The benchmark commands docs/benchmarks.md shows and each bench script's docstring gives."""
    commands = [c for c in fenced_commands(ROOT / "docs" / "benchmarks.md") if c.startswith("scripts/py")]
    for script in sorted((ROOT / "bench").glob("bench_*.py")):
        doc = ast.get_docstring(ast.parse(script.read_text())) or ""
        runs = [re.sub(r"\s*->.*$", "", m) for m in re.findall(r"^\s*(?:Run:\s*)?(\S*python\S* bench/\S+.*|"
                                                                 r"scripts/py bench/\S+.*)$", doc, re.M)]
        assert runs, f"{script.name}: its docstring says no command to run it"
        commands += runs
    return commands


def test_bench_commands_start_as_documented():
    commands = bench_commands()
    scripts = {shlex.split(c)[1] for c in commands}
    assert scripts >= {f"bench/{p.name}" for p in (ROOT / "bench").glob("bench_*.py")}
    for command in commands:
        # [--frames 1500]: options in brackets are optional; the line as written, without them, must start
        words = shlex.split(re.sub(r"\[[^\]]*\]", "", command))
        assert words[0] == "scripts/py", f"{command}: a bare venv python cannot import vibro_msgs"
        check_bench(words)


def test_scripts_py_gives_the_environment_the_graph_benchmarks_need():
    code = "import rclpy, vibro_msgs.msg; print(vibro_msgs.msg.DicFrame.__name__)"
    res = run([str(ROOT / "scripts" / "py"), "-c", code], env=dict(BARE_ENV))
    assert res.returncode == 0 and res.stdout.strip() == "DicFrame", res.stderr[-800:]
    # from another folder too, as a lab's shell would call it
    res = subprocess.run([str(ROOT / "scripts" / "py"), "-c", code], cwd="/", capture_output=True, text=True,
                         timeout=60, env=BARE_ENV)
    assert res.returncode == 0, res.stderr[-800:]


def test_the_parser_sees_what_a_reader_sees():
    # the extraction itself: comments, continuation comments and '&&' chains
    sample = ROOT / "README.md"
    cmds = fenced_commands(sample)
    assert "make demo" in cmds and "make test" in cmds
    assert "cd vibro" in cmds and any(c.startswith("rosdep install") for c in cmds)
    assert not any("#" in c for c in cmds)
