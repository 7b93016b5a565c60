"""rig.yaml validation: every required key, every type, ROIs, number spelling."""

from __future__ import annotations

import copy
import logging
from pathlib import Path

import pytest
import yaml

from vibro_io.rig import _SCHEMA, check_rois_in_image, load_rig, load_yaml, parse_rig, write_rig
from vibro_model.errors import RigError


@pytest.fixture
def rig_data(tiny_recording: Path) -> dict:
    return load_yaml(tiny_recording / "rig.yaml")


def test_scientific_notation_without_dot_is_a_number(tiny_recording: Path) -> None:
    # PyYAML's default resolver returns "3.1e11" and "7e10" as strings; ours must not.
    assert isinstance(yaml.safe_load("x: 3.1e11")["x"], str)  # the trap we avoid
    rig = load_rig(tiny_recording / "rig.yaml")
    assert rig.ball.youngs_modulus_pa == 3.1e11
    assert rig.structure.youngs_modulus_pa == 7e10
    assert rig.ball.mass_kg == 1.82e-4


ALL_KEYS = [(s, k) for s, keys in _SCHEMA.items() for k in keys]


@pytest.mark.parametrize("section,key", ALL_KEYS)
def test_each_missing_required_key_is_named(rig_data: dict, section: str, key: str) -> None:
    data = copy.deepcopy(rig_data)
    del data[section][key]
    with pytest.raises(RigError, match=rf"somefile\.yaml: missing required key '{section}\.{key}'"):
        parse_rig(data, "somefile.yaml")


@pytest.mark.parametrize("section", list(_SCHEMA))
def test_each_missing_section_is_named(rig_data: dict, section: str) -> None:
    data = copy.deepcopy(rig_data)
    del data[section]
    with pytest.raises(RigError, match=rf"missing required key '{section}'"):
        parse_rig(data, "r.yaml")


@pytest.mark.parametrize("section,key", ALL_KEYS)
def test_each_wrong_type_is_named(rig_data: dict, section: str, key: str) -> None:
    data = copy.deepcopy(rig_data)
    data[section][key] = "not-a-number" if key != "ball_roi" and key != "structure_roi" else [1, 2, "x", 4]
    with pytest.raises(RigError, match=rf"r\.yaml: key '{section}\.{key}': expected"):
        parse_rig(data, "r.yaml")


@pytest.mark.parametrize("section,key,value", [
    ("camera", "fps", 0), ("camera", "fps", -1000.0), ("camera", "mm_per_px", 0.0),
    ("dic", "subset_px", 30), ("dic", "ball_roi", [0, 0, 10]), ("dic", "ball_roi", [-1, 0, 40, 40]),
    ("ball", "poisson_ratio", 0.7), ("camera", "fps", True), ("camera", "fps", float("nan")),
])
def test_non_physical_values_are_refused(rig_data: dict, section: str, key: str, value) -> None:
    data = copy.deepcopy(rig_data)
    data[section][key] = value
    with pytest.raises(RigError, match=rf"'{section}\.{key}'"):
        parse_rig(data, "r.yaml")


def test_gap_must_exceed_ball(rig_data: dict) -> None:
    data = copy.deepcopy(rig_data)
    data["structure"]["gap_mm"] = 4.0
    with pytest.raises(RigError, match="structure.gap_mm"):
        parse_rig(data, "r.yaml")


@pytest.mark.parametrize("roi_key", ["ball_roi", "structure_roi"])
def test_roi_outside_image_is_named(rig_data: dict, roi_key: str) -> None:
    data = copy.deepcopy(rig_data)
    data["dic"][roi_key] = [80, 100, 50, 40]  # image is 96 x 128
    rig = parse_rig(data, "r.yaml")
    with pytest.raises(RigError, match=rf"dic\.{roi_key}.*outside the 96x128 px image"):
        check_rois_in_image(rig, 128, 96)


def test_roi_smaller_than_subset_is_refused(rig_data: dict) -> None:
    data = copy.deepcopy(rig_data)
    data["dic"]["ball_roi"] = [10, 10, 20, 60]
    with pytest.raises(RigError, match="smaller than one 31 px subset"):
        check_rois_in_image(parse_rig(data, "r.yaml"), 128, 96)


def test_unknown_keys_warn_and_are_ignored(rig_data: dict, caplog: pytest.LogCaptureFixture) -> None:
    data = copy.deepcopy(rig_data)
    data["camera"]["shutter_s"] = 1e-4
    data["operator"] = "A. N. Other"
    with caplog.at_level(logging.WARNING):
        rig = parse_rig(data, "r.yaml")
    assert rig.camera.fps == 1000.0
    assert "camera.shutter_s" in caplog.text and "'operator'" in caplog.text


def test_missing_and_malformed_files(tmp_path: Path) -> None:
    with pytest.raises(RigError, match="file not found"):
        load_rig(tmp_path / "rig.yaml")
    (tmp_path / "rig.yaml").write_text("camera: [unclosed\n")
    with pytest.raises(RigError, match="not valid YAML"):
        load_rig(tmp_path / "rig.yaml")
    (tmp_path / "rig.yaml").write_text("- just\n- a list\n")
    with pytest.raises(RigError, match="mapping at the top level"):
        load_rig(tmp_path / "rig.yaml")


def test_write_then_read_round_trip(tiny_recording: Path, tmp_path: Path) -> None:
    rig = load_rig(tiny_recording / "rig.yaml")
    write_rig(rig, tmp_path / "rig.yaml")
    again = load_rig(tmp_path / "rig.yaml")
    assert again.to_dict() == rig.to_dict()


def test_old_acceleration_key_still_reads(rig_data: dict, tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    # rig.yaml files written before the unit rename spell the nominal drive excitation.acceleration_ms2
    old, new = copy.deepcopy(rig_data), copy.deepcopy(rig_data)
    old["excitation"]["acceleration_ms2"] = 27.5
    new["excitation"]["acceleration_mps2"] = 27.5
    (tmp_path / "rig.yaml").write_text(yaml.safe_dump(old, sort_keys=False), encoding="utf-8")
    with caplog.at_level(logging.WARNING):
        rig = load_rig(tmp_path / "rig.yaml")
    assert rig.excitation.acceleration_mps2 == 27.5
    assert "unknown key" not in caplog.text
    assert rig.excitation == parse_rig(new, "r.yaml").excitation
    write_rig(rig, tmp_path / "rewritten.yaml")
    written = load_yaml(tmp_path / "rewritten.yaml")["excitation"]
    assert written == {"frequency_hz": rig.excitation.frequency_hz, "acceleration_mps2": 27.5}
    with pytest.raises(RigError, match=r"excitation\.acceleration_ms2"):
        old["excitation"]["acceleration_ms2"] = -1.0
        parse_rig(old, "r.yaml")


def test_old_and_new_acceleration_keys_together_are_refused(rig_data: dict) -> None:
    data = copy.deepcopy(rig_data)
    data["excitation"].update(acceleration_ms2=27.0, acceleration_mps2=27.0)
    with pytest.raises(RigError, match=r"r\.yaml: keys 'excitation\.acceleration_ms2' and "
                                       r"'excitation\.acceleration_mps2' both given"):
        parse_rig(data, "r.yaml")


@pytest.mark.parametrize(("edit", "message"), [
    # the accelerometers block under a misspelt name would be ignored: the run would go on without them
    (lambda d: d.__setitem__("accelerometer", {"file": "accel.csv", "time_column": "time_s",
                                               "upper_column": "upper_ms2", "lower_column": "lower_ms2"}),
     r"unknown key 'accelerometer': misspelt 'accelerometers'\?"),
    # a required key misspelt: the missing key is named with the misspelling beside it
    (lambda d: d["camera"].__setitem__("mm_per_pix", d["camera"].pop("mm_per_px")),
     r"missing required key 'camera.mm_per_px' \(it has 'camera.mm_per_pix': misspelt\?\)"),
    (lambda d: d.__setitem__("camra", d.pop("camera")), r"missing required key 'camera' \(it has 'camra'"),
    # an optional key misspelt would take its default silently
    (lambda d: d["dic"].__setitem__("ball_metod", "outline"),
     r"unknown key 'dic.ball_metod': misspelt 'dic.ball_method'"),
])
def test_a_misspelt_key_is_refused_naming_the_key_it_misspells(rig_data: dict, edit, message: str) -> None:
    data = copy.deepcopy(rig_data)
    edit(data)
    with pytest.raises(RigError, match=message):
        parse_rig(data, "r.yaml")
