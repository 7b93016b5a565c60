"""``vibro --version``: the version package.xml declares and, from a checkout, the commit git reports."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def test_version_names_the_package_version_and_the_checkout_commit():
    run = subprocess.run([sys.executable, "-m", "vibro_app.cli", "--version"], capture_output=True, text=True,
                         cwd="/", timeout=60)
    assert run.returncode == 0 and run.stderr == ""
    declared = re.search(r"<version>([^<]+)</version>", (REPO / "src/vibro_app/package.xml").read_text()).group(1)
    head = subprocess.run(["git", "-C", str(REPO), "rev-parse", "HEAD"], capture_output=True, text=True).stdout.strip()
    match = re.fullmatch(r"vibro (\S+) \(git ([0-9a-f]{10})(-dirty)?\)\n", run.stdout)
    assert match, run.stdout
    assert match.group(1) == declared and head.startswith(match.group(2))
