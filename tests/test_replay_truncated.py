"""vibro replay of a bag cut short (issue #30 item 5): replayed as far as it reads, and said to be incomplete.

Before: exit 0, empty stderr, `complete: true` for 742 of 1500 frames; the summary called the rest "not filmed"
and only bag_source.log knew. The frames the cut file still holds are counted here with the mcap package's
own stream reader (independent of vibro's bag reader).
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

from domains import private_domain

VIBRO = [sys.executable, "-m", "vibro_app.cli"]


def _readable_frames(mcap_file: Path) -> int:
    """vibro/frames messages an MCAP stream reader gets from the file before it breaks off."""
    from mcap.records import Channel, Message
    from mcap.stream_reader import StreamReader

    channels, count = set(), 0
    with open(mcap_file, "rb") as handle:
        try:
            for record in StreamReader(handle, skip_magic=False, emit_chunks=False).records:
                if isinstance(record, Channel) and record.topic.endswith("vibro/frames"):
                    channels.add(record.id)
                elif isinstance(record, Message) and record.channel_id in channels:
                    count += 1
        except Exception:  # noqa: BLE001 - the cut: whatever the reader raises there, what came before counts
            pass
    return count


def test_a_truncated_bag_replays_its_readable_part_and_says_the_rest_is_lost(reference_run: dict,
                                                                            tmp_path: Path) -> None:
    frames_recorded = len(reference_run["truth"]["frames"]["ball_mm"])
    bag = tmp_path / "cut"
    shutil.copytree(reference_run["bag"], bag)
    (mcap_file,) = bag.glob("*.mcap")
    data = mcap_file.read_bytes()
    mcap_file.write_bytes(data[: int(len(data) * 0.55)])  # a copy interrupted half way; metadata.yaml whole
    readable = _readable_frames(mcap_file)
    assert 20 < readable < frames_recorded - 20, readable  # the cut falls inside the frames

    env = dict(os.environ, ROS_DOMAIN_ID=private_domain(), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    res = subprocess.run([*VIBRO, "replay", str(bag), "--out", str(tmp_path / "re")], capture_output=True,
                         text=True, timeout=300, env=env)
    assert res.returncode == 1, res.stdout + res.stderr
    assert "incomplete" in res.stderr and f"frames {readable}..{frames_recorded - 1}" in res.stderr, res.stderr
    doc = json.loads((tmp_path / "re" / "results.json").read_text())
    assert doc["complete"] is False
    report = doc["completeness"]
    assert report["frames_expected"] == frames_recorded and report["frames_answered"] == readable, report
    (gap,) = report["gaps"]
    assert (gap["first"], gap["last"]) == (readable, frames_recorded - 1), gap
    assert "could not give them" in gap["reason"], gap
    # the impacts the lost part hides: the truth's impacts from the first lost frame on, to about one
    t_cut = reference_run["truth"]["frames"]["t_s"][readable]
    hidden = sum(1 for i in reference_run["truth"]["impacts"] if i["t"] >= t_cut)
    assert abs(report["impacts_possibly_missing"] - hidden) <= 1.5, (report, hidden)
    logs = [p.read_text() for p in (tmp_path / "re").rglob("bag_source.log")]
    assert any(f"{readable} of the {frames_recorded} vibro/frames messages" in text for text in logs), logs
