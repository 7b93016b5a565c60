"""Shared test fixtures and paths."""

from __future__ import annotations

import os
import random
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
FIXTURES = REPO / "tests" / "fixtures"
SHARED = REPO.parent / "shared"


@pytest.fixture
def tiny_recording() -> Path:
    """The committed 5-frame recording (see fixtures/make_tiny_recording.py)."""
    return FIXTURES / "tiny_recording"


@pytest.fixture
def ros_domain(monkeypatch: pytest.MonkeyPatch) -> str:
    """A private ROS_DOMAIN_ID so parallel test runs on this machine do not cross-talk."""
    domain = str(random.Random(os.getpid() ^ id(monkeypatch)).randint(1, 100))
    monkeypatch.setenv("ROS_DOMAIN_ID", domain)
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    return domain
