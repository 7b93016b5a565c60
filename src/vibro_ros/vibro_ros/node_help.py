"""``<node> --help``: the usage of a vibro node (parameters, topics read and written), from its source.

``ros2 run vibro_dic dic_tracker --help`` must print what the node takes without starting it
(no DDS participant, no rig file needed). The node class is read, not run: every
``declare(self, name, default, description)`` call gives a parameter, every
``create_publisher``/``create_subscription`` call gives a topic, in the node class and in the
helper classes it hands itself to (``Health(self)`` publishes /diagnostics,
``StatusPublisher(self, ...)`` vibro/status, ``FinalFitResults(self, ...)`` subscribes to the
fitter's results). Defaults, descriptions and topic names are evaluated in the defining
module, so what is printed is what the code uses.
"""

from __future__ import annotations

import ast
import inspect
import sys
import textwrap
from dataclasses import dataclass
from pathlib import Path
from typing import Any

HELP_FLAGS = ("-h", "--help")


@dataclass(frozen=True)
class ParameterDoc:
    name: str
    default: Any
    description: str


@dataclass(frozen=True)
class TopicDoc:
    name: str
    msg_type: str  # package/msg/Type
    direction: str  # "publishes" or "subscribes"


@dataclass
class NodeInterface:
    parameters: list[ParameterDoc]
    topics: list[TopicDoc]


_UNRESOLVED = object()
#: a default computed when the node starts (e.g. the readers a node declares for itself)
NODE_DEFAULT = object()


def _evaluate(expr: ast.expr, namespace: dict[str, Any]) -> Any:
    """``expr`` evaluated in a module's globals; _UNRESOLVED when it needs run-time values."""
    try:
        return eval(compile(ast.Expression(body=expr), "<node_help>", "eval"), dict(namespace))  # noqa: S307
    except Exception:
        return _UNRESOLVED


def _ros_type_name(cls: Any) -> str:
    """``pkg/msg/Type`` of a generated message class (``sensor_msgs.msg._image.Image``)."""
    if isinstance(cls, type):
        return f"{cls.__module__.split('.')[0]}/msg/{cls.__name__}"
    return "?"


def _loop_iterables(tree: ast.AST) -> dict[str, ast.expr]:
    """Loop variable name -> the iterable expression of ``for <name> in <iterable>`` loops."""
    return {n.target.id: n.iter for n in ast.walk(tree)
            if isinstance(n, ast.For) and isinstance(n.target, ast.Name)}


def _topic_names(expr: ast.expr, namespace: dict[str, Any], loops: dict[str, ast.expr]) -> list[tuple[str, str]]:
    """(name, msg_type or "") of the topic(s) a name argument stands for; a loop over Topic objects
    (``for topic in topics.ALL_TOPICS: ... topic.name``) stands for all of them."""
    value = _evaluate(expr, namespace)
    if isinstance(value, str):
        return [(value, "")]
    root = expr
    while isinstance(root, ast.Attribute):
        root = root.value
    if isinstance(root, ast.Name) and root.id in loops:
        items = _evaluate(loops[root.id], namespace)
        if items is not _UNRESOLVED:
            return [(t.name, getattr(t, "msg_type", "")) for t in items if hasattr(t, "name")]
    return [(f"<{ast.unparse(expr)}>", "")]


def _scan_class(cls: Any, interface: NodeInterface, seen: set) -> None:
    """Parameters and topics declared in the source of ``cls`` (a class or a function taking the node)."""
    if cls in seen:
        return
    seen.add(cls)
    try:
        source = textwrap.dedent(inspect.getsource(cls))
    except (OSError, TypeError):
        return
    namespace = vars(sys.modules[cls.__module__])
    tree = ast.parse(source)
    loops = _loop_iterables(tree)
    calls = sorted((n for n in ast.walk(tree) if isinstance(n, ast.Call)), key=lambda n: (n.lineno, n.col_offset))
    for call in calls:  # in source order
        func = call.func
        fname = func.attr if isinstance(func, ast.Attribute) else func.id if isinstance(func, ast.Name) else ""
        if fname == "declare" and len(call.args) >= 4:
            name = _evaluate(call.args[1], namespace)
            default = _evaluate(call.args[2], namespace)
            description = _evaluate(call.args[3], namespace)
            interface.parameters.append(ParameterDoc(
                str(name) if name is not _UNRESOLVED else ast.unparse(call.args[1]),
                default if default is not _UNRESOLVED else NODE_DEFAULT,
                str(description) if description is not _UNRESOLVED else ast.unparse(call.args[3])))
        elif fname in ("create_publisher", "create_subscription") and len(call.args) >= 2:
            msg_cls = _evaluate(call.args[0], namespace)
            direction = "publishes" if fname == "create_publisher" else "subscribes"
            for name, msg_type in _topic_names(call.args[1], namespace, loops):
                interface.topics.append(TopicDoc(name, msg_type or _ros_type_name(msg_cls), direction))
        elif fname in ("results_subscription", "ResultsSubscription") and len(call.args) >= 3:
            # vibro_ros.adaptive_qos: (node, msg class, topic, ...) -- one subscription as far as users are concerned
            msg_cls = _evaluate(call.args[1], namespace)
            for name, msg_type in _topic_names(call.args[2], namespace, loops):
                interface.topics.append(TopicDoc(name, msg_type or _ros_type_name(msg_cls), "subscribes"))
        elif any(isinstance(a, ast.Name) and a.id in ("self", "node") for a in call.args):
            helper = _evaluate(func, namespace)  # a helper class or function the node hands itself to
            if isinstance(helper, type) or inspect.isfunction(helper):
                _scan_class(helper, interface, seen)


def node_interface(node_class: type) -> NodeInterface:
    """Parameters and topics of ``node_class`` (see the module docstring), in source order, deduplicated."""
    interface = NodeInterface([], [])
    _scan_class(node_class, interface, set())
    params: dict[str, ParameterDoc] = {}
    for p in interface.parameters:
        params.setdefault(p.name, p)
    topics: dict[tuple[str, str], TopicDoc] = {}
    for t in interface.topics:
        topics.setdefault((t.name, t.direction), t)
    return NodeInterface(list(params.values()), list(topics.values()))


def parameter_type_name(value: Any) -> str:
    """The ROS parameter type of a Python value, as ``--help`` and parameter errors name it (bool, int, double,
    string, string[], ...)."""
    if isinstance(value, bool):
        return "bool"
    if isinstance(value, int):
        return "int"
    if isinstance(value, float):
        return "double"
    if isinstance(value, str):
        return "string"
    if isinstance(value, (list, tuple)):
        return f"{parameter_type_name(value[0]) if value else 'string'}[]"
    return type(value).__name__


def _format_default(value: Any) -> str:
    if isinstance(value, str):
        return repr(value).replace("'", '"')
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_format_default(v) for v in value) + "]"
    return str(value).lower() if isinstance(value, bool) else str(value)


def _module_name(node_class: type) -> str:
    """The dotted module name of ``node_class``, also when it runs as ``python -m`` (``__main__``)."""
    name = node_class.__module__
    if name == "__main__":
        spec = getattr(sys.modules["__main__"], "__spec__", None)
        name = spec.name if spec is not None else name
    return name


def usage(node_class: type, executable: str | None = None) -> str:
    """The ``--help`` text of a node: summary, how to start it, parameters, topics read and written."""
    module = sys.modules[node_class.__module__]
    module_name = _module_name(node_class)
    package = module_name.split(".")[0]
    executable = executable or module_name.rsplit(".", 1)[-1].removesuffix("_node")
    summary = inspect.cleandoc(module.__doc__ or node_class.__doc__ or "").split("\n\n")[0]
    interface = node_interface(node_class)
    lines = [f"usage: ros2 run {package} {executable} [--help] [--ros-args --params-file vibro.yaml "
             f"-p NAME:=VALUE ... -r __ns:=/NAMESPACE -r FROM:=TO ...]", "", summary, "",
             "parameters (-p NAME:=VALUE or a params file; lab defaults: share/vibro_bringup/config/vibro.yaml):"]
    width = max((len(p.name) for p in interface.parameters), default=0)
    for p in interface.parameters:
        default = ("default set by the node" if p.default is NODE_DEFAULT
                   else f"{parameter_type_name(p.default)}, default {_format_default(p.default)}")
        lines.append(f"  {p.name:<{width}}  {default}: {p.description}")
    for direction, title in (("subscribes", "reads (subscribes to)"), ("publishes", "writes (publishes)")):
        lines += ["", f"{title}:"]
        found = [t for t in interface.topics if t.direction == direction]
        tw = max((len(t.name) for t in found), default=0)
        lines += [f"  {t.name:<{tw}}  {t.msg_type}" for t in found] or ["  (none)"]
    lines += ["", "Topic names without a leading slash are relative to the node's namespace "
                  "(-r __ns:=/lab1 gives /lab1/vibro/...); /diagnostics stays absolute.",
              "Exit codes: 0 done or stopped by SIGINT/SIGTERM, 2 bad parameter or input file (one line on the log)."]
    return "\n".join(lines) + "\n"


def handle_command_line(node_class: type, argv: list[str]) -> int | None:
    """Handle the node's non-ROS arguments (those before ``--ros-args``).

    ``-h``/``--help`` prints :func:`usage` and gives 0; any other argument gives 2 with one line
    on stderr (a mistyped option must not start a node that silently ignores it). None: no
    such argument, start the node.
    """
    from rclpy.utilities import remove_ros_args

    executable = Path(argv[0]).name if argv else ""
    if not executable.isidentifier():  # "python -m pkg.module" or a script path: no ros2 run name
        executable = None
    extra = remove_ros_args(args=list(argv))[1:]
    if any(a in HELP_FLAGS for a in extra):
        sys.stdout.write(usage(node_class, executable))
        return 0
    if extra:
        name = executable or _module_name(node_class)
        print(f"{name}: error: unknown argument(s) {' '.join(extra)} (ROS arguments go after --ros-args; "
              f"see --help)", file=sys.stderr)
        return 2
    return None
