"""``vibro bag reindex <bag>``: make a bag whose recorder was killed open everywhere again.

Like ``ros2 bag reindex``: the MCAP file is rewritten with its summary and index (every
message up to the last complete chunk; the cut original stays as ``<file>.cut``) and
metadata.yaml with the real counts, so rosbags, mcap's indexed reader and ``ros2 bag``
open it. vibro's own commands read a cut bag without this.
"""

from __future__ import annotations

import argparse

from vibro_ros.bags import reindex


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("bag", help="bag maintenance (reindex a bag cut short)")
    bag_sub = p.add_subparsers(dest="bag_command", metavar="BAG_COMMAND", required=True)
    r = bag_sub.add_parser("reindex", help="rewrite a cut bag's MCAP index and metadata.yaml (like ros2 bag reindex)")
    r.add_argument("bag", help="bag directory (rosbag2, MCAP storage)")
    r.add_argument("--no-backup", action="store_true", help="do not keep the cut original as <file>.cut")
    r.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    report = reindex(args.bag, keep_backup=not args.no_backup)
    for topic, count in sorted(report.per_topic.items()):
        print(f"{topic}: {count}")
    print(f"reindexed {report.bag}: {report.messages} messages"
          + (f"; cut original kept as {', '.join(str(p) for p in report.backups)}" if report.backups else ""))
    return 0
