"""CPU seconds of the test suite per test file (issue 41: a suite under 5 minutes on two cores).

    VIBRO_TEST_CPU_LOG=/tmp/cpu.jsonl make test      # tests/conftest.py appends one line per test
    scripts/py bench/suite_cpu.py /tmp/cpu.jsonl [--top 30] [--json bench/results/suite_cpu.json]
                                 [--costs tests/file_costs.json]

Each line holds a test's CPU time from setup to teardown: the pytest worker's own and that of every process it
started and waited for (a graph's nodes included). A module fixture's cost lands on its file's first test.
Prints the files by CPU, the total, and what two cores need for it at best (total / 2). ``--costs`` writes the
per-file CPU seconds that tests/conftest.py orders the files by (heaviest first, for the xdist workers), and their
wall seconds.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import defaultdict
from pathlib import Path


def per_file(rows: list[dict]) -> dict[str, dict[str, float]]:
    """{test file: {"cpu_s", "wall_s", "tests"}} from the log's rows."""
    out: dict[str, dict[str, float]] = defaultdict(lambda: {"cpu_s": 0.0, "wall_s": 0.0, "tests": 0})
    for r in rows:
        f = out[r["test"].split("::", 1)[0]]
        f["cpu_s"] += float(r["cpu_s"])
        f["wall_s"] += float(r["wall_s"])
        f["tests"] += 1
    return dict(out)


def file_costs(files: dict[str, dict[str, float]]) -> dict[str, dict[str, float]]:
    """{"cpu_s": {test file name: CPU seconds}, "wall_s": {...: wall seconds}}, 0.1 s resolution, each file
    list heaviest first by CPU: the order tests/conftest.py runs them in."""
    order = sorted(files, key=lambda name: -files[name]["cpu_s"])
    return {key: {Path(name).name: round(files[name][key], 1) for name in order} for key in ("cpu_s", "wall_s")}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("log", type=Path)
    parser.add_argument("--top", type=int, default=30)
    parser.add_argument("--json", type=Path, default=None)
    parser.add_argument("--costs", type=Path, default=None,
                        help="write each file's CPU and wall seconds here (tests/file_costs.json)")
    args = parser.parse_args(argv)
    try:
        rows = [json.loads(line) for line in args.log.read_text().splitlines() if line.strip()]
    except (OSError, json.JSONDecodeError) as exc:
        print(f"suite_cpu: {args.log}: {exc}", file=sys.stderr)
        return 2
    files = per_file(rows)
    total = sum(f["cpu_s"] for f in files.values())
    print(f"{len(rows)} tests in {len(files)} files: {total:.0f} CPU-s, {total / 2:.0f} s on two cores at best")
    print(f"{'cpu_s':>8} {'share':>6} {'wall_s':>8} {'tests':>5}  file")
    for name, f in sorted(files.items(), key=lambda kv: -kv[1]["cpu_s"])[:args.top]:
        print(f"{f['cpu_s']:8.1f} {100 * f['cpu_s'] / total:5.1f}% {f['wall_s']:8.1f} {f['tests']:5d}  {name}")
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps({"tests": len(rows), "cpu_s": total, "files": files}, indent=1))
    if args.costs:
        args.costs.write_text(json.dumps(file_costs(files), indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
