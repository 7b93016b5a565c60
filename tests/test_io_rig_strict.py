"""rig.yaml written twice over: a key repeated at any depth is refused with both line numbers.

Built from the rig.yaml of a real `vibro synth` recording (PyYAML alone would silently keep the
last value: fps 500 instead of 1000 halves every velocity).
"""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
import yaml

from vibro_app.cli import main
from vibro_io.recording import open_recording
from vibro_io.rig import load_rig
from vibro_model.errors import RigError


@pytest.fixture(scope="module")
def synth(tmp_path_factory) -> Path:
    from vibro_sim.synth import SynthConfig, synthesize

    out = tmp_path_factory.mktemp("rig") / "rec"
    synthesize(out, SynthConfig(frames=300, seed=13), progress=False)
    return out


@pytest.fixture
def rec(synth, tmp_path) -> Path:
    dst = tmp_path / "rec"
    shutil.copytree(synth, dst)
    return dst


def _insert_after(rec: Path, anchor: str, new_line: str) -> tuple[int, int]:
    """Insert ``new_line`` after the line starting with ``anchor``; (anchor line, new line), 1-based."""
    lines = (rec / "rig.yaml").read_text().splitlines()
    at = next(i for i, line in enumerate(lines) if line.startswith(anchor))
    lines.insert(at + 1, new_line)
    (rec / "rig.yaml").write_text("\n".join(lines) + "\n")
    return at + 1, at + 2


def test_duplicate_fps_is_refused_naming_key_and_both_lines(rec, capsys) -> None:
    first, second = _insert_after(rec, "  fps:", "  fps: 500.0")
    assert yaml.safe_load((rec / "rig.yaml").read_text())["camera"]["fps"] == 500.0  # the silent trap
    with pytest.raises(RigError, match=rf"rig.yaml: key 'camera.fps' appears twice, on lines {first} and {second}"):
        load_rig(rec / "rig.yaml")
    assert main(["info", str(rec)]) == 2
    err = capsys.readouterr().err.strip()
    assert "camera.fps" in err and len(err.splitlines()) == 1


def test_duplicate_section_at_top_level_is_refused(rec) -> None:
    text = (rec / "rig.yaml").read_text()
    lines = text.splitlines()
    (rec / "rig.yaml").write_text(text + "excitation:\n  frequency_hz: 30.0\n")
    first = next(i for i, line in enumerate(lines) if line.startswith("excitation:")) + 1
    with pytest.raises(RigError, match=rf"key 'excitation' appears twice, on lines {first} and {len(lines) + 1}"):
        open_recording(rec)


def test_duplicate_in_accelerometers_block_is_refused(rec) -> None:
    first, second = _insert_after(rec, "  time_column:", "  time_column: t_ms")
    with pytest.raises(RigError, match=rf"'accelerometers.time_column' appears twice, on lines {first} and {second}"):
        load_rig(rec / "rig.yaml")


def test_duplicate_inside_a_list_of_mappings_is_refused(tmp_path) -> None:
    # any depth: a mapping inside a sequence too (unknown keys are otherwise only warned about)
    path = tmp_path / "x.yaml"
    path.write_text("notes:\n  - who: A\n    who: B\n")
    with pytest.raises(RigError, match=r"key 'notes\[0\].who' appears twice, on lines 2 and 3"):
        load_rig(path)

