"""The ``vibro`` command line: one subcommand per job, each defined next to its core.

Each module in :data:`SUBCOMMAND_MODULES` exposes ``register(subparsers)``, which adds
its parser and sets ``func`` to a ``run(args) -> int``. Bad input raises
:class:`vibro_model.errors.RecordingError`; it is printed as one line, without a traceback.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys

from vibro_model.errors import RecordingError
from vibro_model.threads import one_blas_thread

from .version import version_text

one_blas_thread()   # before the subcommands load numpy, scipy or OpenCV (vibro_model.threads)

SUBCOMMAND_MODULES = (
    "vibro_app.cmd_info",
    "vibro_app.cmd_init",
    "vibro_app.cmd_synth",
    "vibro_app.cmd_calibrate",
    "vibro_app.cmd_track",
    "vibro_app.cmd_fit",
    "vibro_app.cmd_analyze",
    "vibro_app.cmd_campaign",
    "vibro_app.cmd_graph",
    "vibro_app.bag_results",
    "vibro_app.cmd_replay",
    "vibro_app.cmd_bag",
    "vibro_eval.cli",
)


class _VersionAction(argparse.Action):
    """--version, worked out only when asked for (it runs git)."""

    def __init__(self, option_strings: list[str], dest: str, **kwargs: object) -> None:
        super().__init__(option_strings, dest, nargs=0, default=argparse.SUPPRESS, **kwargs)

    def __call__(self, parser: argparse.ArgumentParser, *args: object) -> None:
        print(version_text())
        parser.exit()


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="vibro",
        description="Characterise vibro-impact absorbers from high-speed video and accelerometers.",
    )
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    parser.add_argument("--version", action=_VersionAction,
                        help="print the package version (and the git commit of a checkout) and exit")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in SUBCOMMAND_MODULES:
        try:
            module = importlib.import_module(name)
        except ModuleNotFoundError as exc:
            # subcommand not written yet, or its package not installed (vibro_eval, the evaluation
            # harness, is a dev package: a runtime install has no `vibro prove`)
            if exc.name in (name, name.split(".")[0]):
                continue
            raise
        module.register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    args.command_line = ["vibro", *(sys.argv[1:] if argv is None else argv)]   # as typed (results' provenance)
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.INFO,
        format="%(levelname)s %(name)s: %(message)s",
    )
    if not getattr(args, "func", None):
        parser.print_help()
        return 1
    try:
        return int(args.func(args) or 0)
    except RecordingError as exc:
        print(f"vibro {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"vibro {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
