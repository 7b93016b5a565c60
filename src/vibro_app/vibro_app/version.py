"""``vibro --version``: the package version and, when run from a git checkout, its commit."""

from __future__ import annotations

import re
import subprocess
from importlib import metadata
from pathlib import Path


def package_version() -> str:
    """vibro_app's installed version, else the one its package.xml declares (a source tree), else 'unknown'."""
    try:
        return metadata.version("vibro_app")
    except metadata.PackageNotFoundError:
        pass
    package_xml = Path(__file__).resolve().parents[1] / "package.xml"
    if package_xml.is_file():
        found = re.search(r"<version>\s*([^<\s]+)\s*</version>", package_xml.read_text(encoding="utf-8"))
        if found:
            return found.group(1)
    return "unknown"


def checkout_commit() -> str | None:
    """The short commit of the git checkout this file lies in (with '-dirty' when files changed), else None."""
    here = Path(__file__).resolve().parent
    try:
        commit = subprocess.run(["git", "-C", str(here), "rev-parse", "--short=10", "HEAD"], capture_output=True,
                                text=True, timeout=5)
        if commit.returncode != 0:
            return None
        dirty = subprocess.run(["git", "-C", str(here), "status", "--porcelain", "--untracked-files=no"],
                               capture_output=True, text=True, timeout=5)
    except (OSError, subprocess.SubprocessError):
        return None
    return commit.stdout.strip() + ("-dirty" if dirty.stdout.strip() else "")


def version_text() -> str:
    """'vibro 0.1.0 (git 0123abcd45)' or 'vibro 0.1.0' outside a checkout."""
    commit = checkout_commit()
    return f"vibro {package_version()}" + (f" (git {commit})" if commit else "")
