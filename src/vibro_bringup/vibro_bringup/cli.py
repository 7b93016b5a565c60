"""The ``vibro`` command line: one subcommand per job, each defined next to its core.

Each module in :data:`SUBCOMMAND_MODULES` exposes ``register(subparsers)``, which adds
its parser and sets ``func`` to a ``run(args) -> int``. Bad input raises
:class:`vibro_io.errors.RecordingError`; it is printed as one line, without a traceback.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys

from vibro_io.errors import RecordingError

SUBCOMMAND_MODULES = (
    "vibro_bringup.cmd_info",
    "vibro_bringup.cmd_init",
    "vibro_sim.cli",
    "vibro_dic.cli",
    "vibro_fit.cli",
    "vibro_bringup.cmd_analyze",
    "vibro_bringup.cmd_campaign",
    "vibro_bringup.cmd_graph",
    "vibro_bringup.bag_results",
    "vibro_bringup.cmd_replay",
    "vibro_bringup.cmd_bag",
    "vibro_eval.cli",
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="vibro",
        description="Characterise vibro-impact absorbers from high-speed video and accelerometers.",
    )
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
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
