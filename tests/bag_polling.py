"""Waiting on a bag that its recorder is still writing (tests kill recorders mid-write)."""

from __future__ import annotations

import logging
from pathlib import Path

from vibro_ros.bags import BagError, read_messages


def readable(bag: Path, topic: str) -> int:
    """How many ``topic`` messages the bag's MCAP holds readable now (while its recorder still writes it)."""
    logging.disable(logging.WARNING)  # its truncated last chunk is expected here
    try:
        return sum(1 for _ in read_messages(bag, {topic}))
    except BagError:
        return 0
    finally:
        logging.disable(logging.NOTSET)
