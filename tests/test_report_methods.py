"""report.html as a referee reads it (issue 39 item 1): the methods as run, the uncertainty, what was lost, how to
reproduce, vector figures, and one deviation D quoted and drawn.

One short synthetic recording (800 frames, 3 of them made unreadable) is synthesized and analysed once by the
vibro command, as a user runs it (its own folder); each test reads report.html back (parsed) and holds it against
an independent source: rig.yaml read here, hashlib on the files, the three frames this module broke, a second run of
the command printed on the page, the SVG files parsed as XML.
"""

from __future__ import annotations

import hashlib
import json
import re
import shlex
import shutil
import subprocess
import xml.etree.ElementTree as ET
from html.parser import HTMLParser
from pathlib import Path

import pytest
import yaml
from test_report_summary import keys_of

from vibro_app.findings_text import percent, value_pm
from vibro_app.report_lost import lost_html
from vibro_fit.segmentation import SegmentationConfig

ROOT = Path(__file__).resolve().parents[1]
VIBRO = ROOT / "vibro"
FRAMES = 800
BROKEN = (300, 301, 302)   # frames this module overwrites with bytes that are no image


class Page(HTMLParser):
    """Rows with a data-key (key -> cell texts), elements by id (id -> text), links, and the text of elements."""

    def __init__(self) -> None:
        super().__init__()
        self.rows: dict[str, list[str]] = {}
        self.ids: dict[str, str] = {}
        self.links: list[str] = []
        self.text: list[str] = []
        self._row: str | None = None
        self._cell: list[str] | None = None
        self._open: list[tuple[str, str, list[str]]] = []   # (tag, id, text) of elements with an id

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        if tag == "a" and a.get("href"):
            self.links.append(a["href"])
        if tag == "tr" and a.get("data-key"):
            self._row = a["data-key"]
            self.rows[self._row] = []
        if self._row and tag in ("td", "th"):
            self._cell = []
        if a.get("id"):
            self._open.append((tag, a["id"], []))

    def handle_endtag(self, tag):
        if self._row and tag in ("td", "th") and self._cell is not None:
            self.rows[self._row].append(" ".join("".join(self._cell).split()))
            self._cell = None
        if tag == "tr":
            self._row = None
        if self._open and self._open[-1][0] == tag:
            _, ident, text = self._open.pop()
            self.ids[ident] = "".join(text)

    def handle_data(self, data):
        self.text.append(data)
        if self._cell is not None:
            self._cell.append(data)
        for _, _, text in self._open:
            text.append(data)


def vibro(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    done = subprocess.run([str(VIBRO), *args], cwd=cwd, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    return done


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """(base folder, results.json, parsed report, report text) of one ``vibro analyze`` run, relative paths."""
    base = tmp_path_factory.mktemp("report_methods")   # its own folder: rec/ and out/ of this module only
    vibro("synth", "--out", "rec", "--seed", "11", "--frames", str(FRAMES), "--effect", "coulomb_friction",
          "--cor-scatter", "0.01", "--noise", "2", "--no-progress", cwd=base)
    for k in BROKEN:
        (base / "rec" / "frames" / f"{k:06d}.png").write_bytes(b"not an image")
    vibro("analyze", "rec", "--out", "out", "--no-progress", cwd=base)
    text = (base / "out" / "report.html").read_text(encoding="utf-8")
    page = Page()
    page.feed(text)
    return base, json.loads((base / "out" / "results.json").read_text()), page, text


def cell(page: Page, key: str) -> str:
    assert key in page.rows, (key, sorted(page.rows))
    return page.rows[key][-1]


def test_methods_numbers_are_rig_yaml_and_results(run):
    base, doc, page, _ = run
    rig = yaml.safe_load((base / "rec" / "rig.yaml").read_text())      # the file, read here
    assert cell(page, "dic.subset") == f"{rig['dic']['subset_px']} px"
    assert cell(page, "dic.mesh_step") == f"{rig['dic']['mesh_step_px']} px"
    for body, roi_key in (("ball", "ball_roi"), ("structure", "structure_roi")):
        tex = doc["dic_quality"]["texture"]["bodies"][body]
        x, y, w, h = rig["dic"][roi_key]
        m = re.fullmatch(r"(\d+) subsets of (\d+) px \((\d+) usable\), ROI x (\d+), y (\d+), (\d+) × (\d+) px",
                         cell(page, f"dic.mesh.{body}"))
        assert m, cell(page, f"dic.mesh.{body}")
        assert (int(m[1]), int(m[3])) == (tex["n_subsets"], tex["n_usable"]) and int(m[2]) == rig["dic"]["subset_px"]
        assert tuple(map(int, m.groups()[3:])) == (x, y, w, h)
    # the fit thresholds: the ones vibro analyze runs with (SegmentationConfig's), as results.json records them
    seg = SegmentationConfig()
    assert doc["provenance"]["settings"]["identification"]["segmentation"]["min_points"] == seg.min_points
    assert cell(page, "fit.min_points") == f"from {seg.min_points} frames"
    assert cell(page, "fit.impact_frames").startswith(f"a cluster of at most {seg.max_impact_frames} contact frames")
    m = re.fullmatch(r"parabola residual rms ≤ ([\d.]+) σ \+ ([\d.]+) µm and \|2a \+ g\| ≤ ([\d.]+) g",
                     cell(page, "fit.free"))
    assert m and (float(m[1]), float(m[2]), float(m[3])) == (seg.rms_factor, 1e3 * seg.rms_floor_mm,
                                                            seg.max_friction_g)
    m = re.match(r"\|acceleration \+ g\| > max\(([\d.]+) σ of the estimate, ([\d.]+) m/s²\)", cell(page, "fit.contact"))
    assert m and (float(m[1]), float(m[2])) == (seg.k_sigma, seg.min_threshold_mps2)
    flights = doc["flights"]
    assert cell(page, "fit.flights").startswith(f"{len(flights)} fitted, {sum(f['free'] for f in flights)} free")
    assert cell(page, "fit.structure").startswith(f"one fit over {doc['structure']['n_points']} frames")
    hist = re.search(r"1/([\d.]+) Hz", cell(page, "fit.local_structure"))
    assert hist and float(hist[1]) == rig["excitation"]["frequency_hz"]
    # each plate against the structure, as results.json's plate_motion says (a still plate gives its reason)
    for plate, motion in doc["plate_motion"].items():
        words = f"{plate}: {motion['reason']}" if motion["shape"] in ("still", "too_few") else f"{plate}: "
        assert words in cell(page, "fit.plate_motion"), (plate, motion)
    # the drive's windows and the clock as results.json has them
    assert f"windows of {doc['drive']['window_cycles']} drive cycles" in cell(page, "drive.windows")
    c = doc["accelerometers"]["clock_offset"]
    assert value_pm(1e3 * c["offset_s"], 1e3 * c["offset_std_s"], "ms") in cell(page, "clock")
    # every equation of the paper, each with its number; the COR count of Eq. 16 is the impacts'
    assert [k for k in page.rows if k.startswith("eq.")] == [f"eq.{n}" for n in ("1", "2, 13", "3, 14", "15", "16",
                                                                                  "17", "18")]
    n_cor = sum(i["cor"] is not None for i in doc["impacts"])
    assert cell(page, "eq.16").startswith(f"{n_cor} CORs") and n_cor > 10
    assert f"ball mass {rig['ball']['mass_kg']:g} kg" in cell(page, "eq.17")
    # the final model and the stages that chose it
    chosen = doc["discrepancy"]["stages"]["flights"]["chosen"]
    assert chosen == ["coulomb_friction"] and page.rows["stage.flights"][1] == "Coulomb friction"


def test_uncertainty_says_what_the_sigma_holds(run):
    base, doc, page, _ = run
    text = " ".join(page.ids["uncertainty"].split())
    rig = yaml.safe_load((base / "rec" / "rig.yaml").read_text())
    assert "cancels in their ratio (Eq. 16)" in text and f"({rig['camera']['mm_per_px']:g} mm/px" in text
    assert "Not in the sigma: model error" in text and "Table 2" in text
    stds = sorted(i["cor_std"] for i in doc["impacts"] if i["cor_std"] is not None)
    assert f"over {len(stds)} impacts" in text


def test_reproduce_block_hashes_are_the_files(run):
    base, doc, page, _ = run
    table = re.findall(r"<tr><td>([^<]+)</td><td><code data-verbatim=\"path\">([^<]+)</code></td><td>[^<]+</td>"
                       r"<td>[^<]+</td><td><code class=\"sha256\">([0-9a-f]{64})</code></td></tr>", run[3])
    digests = {role: (path, sha) for role, path, sha in table}
    assert set(digests) == {"frames", "rig.yaml", "accelerometers"}
    rec = base / "rec"
    assert digests["rig.yaml"] == ("rec/rig.yaml", hashlib.sha256((rec / "rig.yaml").read_bytes()).hexdigest())
    assert digests["accelerometers"][1] == hashlib.sha256((rec / "accel.csv").read_bytes()).hexdigest()
    # the frames folder: the documented sha256sum pipeline, run by the shell where it exists, else hashlib
    frames = rec / "frames"
    if shutil.which("sha256sum") and shutil.which("find"):
        out = subprocess.run("(find . -type f -printf '%P\\n' | LC_ALL=C sort | xargs -d '\\n' sha256sum) | sha256sum",
                             shell=True, cwd=frames, capture_output=True, text=True, check=True).stdout.split()[0]
    else:
        lines = "".join(f"{hashlib.sha256(p.read_bytes()).hexdigest()}  {p.name}\n" for p in sorted(frames.iterdir()))
        out = hashlib.sha256(lines.encode()).hexdigest()
    assert digests["frames"][1] == out
    # rig.yaml verbatim, the version, the commit (a 40-hex commit or "unknown"), and results.json says the same
    assert page.ids["rig-yaml"] == (rec / "rig.yaml").read_text()
    prov = doc["provenance"]
    assert {i["role"]: i["sha256"] for i in prov["inputs"]} == {k: v[1] for k, v in digests.items()}
    assert re.fullmatch(r"[0-9a-f]{40}|unknown", prov["git_commit"]) and prov["git_commit"] in run[3]
    assert f"vibro {prov['vibro_version']}" in " ".join(page.text)
    assert prov["hash_bytes"] == sum(i["bytes"] for i in prov["inputs"]) and prov["hash_seconds"] > 0


def test_the_command_on_the_page_reproduces_the_impacts(run):
    base, doc, page, _ = run
    line = page.ids["command"]
    m = re.fullmatch(r"cd (\S+) && (.+)", line)
    assert m, line
    cwd, argv = Path(shlex.split(m[1])[0]), shlex.split(m[2])
    assert cwd.resolve() == base.resolve() and argv[:2] == ["vibro", "analyze"]
    assert argv == doc["provenance"]["command"] == ["vibro", "analyze", "rec", "--out", "out", "--no-progress"]
    argv[argv.index("--out") + 1] = "again"                    # the same command into another folder
    vibro(*argv[1:], cwd=cwd)
    again = json.loads((base / "again" / "results.json").read_text())
    assert len(again["impacts"]) == len(doc["impacts"]) > 10
    for a, b in zip(again["impacts"], doc["impacts"]):
        assert (a["index"], a["plate"]) == (b["index"], b["plate"])
        assert a["t"] == pytest.approx(b["t"], abs=1e-12) and a["cor"] == pytest.approx(b["cor"], abs=1e-12)
    assert [i["sha256"] for i in again["provenance"]["inputs"]] == [i["sha256"] for i in doc["provenance"]["inputs"]]


def test_every_png_has_an_svg_twin_linked(run):
    base, _, page, _ = run
    out = base / "out"
    pngs = sorted(out.glob("*.png"))
    assert {p.name for p in pngs} >= {"displacements.png", "cor_per_impact.png", "discrepancy.png"}
    for png in pngs:
        svg = png.with_suffix(".svg")
        assert svg.is_file(), svg
        root = ET.parse(svg).getroot()
        assert root.tag.endswith("svg") and len(list(root.iter())) > 50, svg
        assert svg.name in page.links, svg.name


def svg_texts(path: Path) -> list[str]:
    return ["".join(t.itertext()) for t in ET.parse(path).getroot().iter() if t.tag.endswith("text")]


def test_the_discrepancy_figure_shows_the_d_the_text_quotes(run):
    base, doc, page, _ = run
    quoted = re.search(r"D baseline ([\d.]+ %), final ([\d.]+ %)", " ".join(" ".join(page.text).split()))
    assert quoted
    disc = doc["discrepancy"]
    assert (quoted[1], quoted[2]) == (percent(disc["baseline_deviation"]), percent(disc["final_deviation"]))
    legend = [t for t in svg_texts(base / "out" / "discrepancy.svg") if re.search(r"\(D = [\d.]+ %\)", t)]
    drawn = [re.search(r"\(D = ([\d.]+ %)\)", t)[1] for t in legend]
    assert drawn == [quoted[1], quoted[2]], legend
    assert legend[0].startswith("baseline") and ("Coulomb friction" in legend[1] or "coulomb_friction" in legend[1])
    # the free-running D of the paper is another number, named as such on the page, never drawn as "D"
    paper = percent(disc["paper_baseline_deviation"])
    assert paper != quoted[1] and paper not in drawn
    which = " ".join(page.ids["which-d"].split())
    assert f"{quoted[1]} → {quoted[2]}" in which and paper in which and "free-running" in which


def test_the_lost_table_says_what_results_json_says(run):
    _, doc, page, _ = run
    for body in ("ball", "structure"):
        c = doc["dic_quality"]["correlation"]["bodies"][body]
        row = page.rows[f"frames.{body}"]
        assert (int(row[1]), int(row[2])) == (c["frames_lost"], c["frames"]) == (len(BROKEN), FRAMES)
        assert row[3] == "frames " + ", ".join(map(str, BROKEN))    # the frames this module broke
    lost = " ".join(page.ids["lost"].split()) if "lost" in page.ids else ""
    tail = " ".join("".join(page.text).split())
    no_cor = len(doc["identification"]["impacts_without_cor"]) + sum(i["cor"] is None for i in doc["impacts"])
    not_free = sum(not f["free"] for f in doc["flights"])
    for key, n, words in (("impacts.no_cor", no_cor, "impacts without a COR"),
                          ("flights.not_free", not_free, "flights not free (no COR or friction from them)")):
        if n:
            assert int(page.rows[key][1]) == n
        else:
            assert key not in page.rows and f"{words}: 0 of" in tail, lost


def test_nothing_lost_says_so(run):
    _, doc, _, _ = run
    whole = json.loads(json.dumps(doc))
    for c in whole["dic_quality"]["correlation"]["bodies"].values():
        c["frames_lost"], c["first_lost"] = 0, []
    for f in whole["flights"]:
        f["free"] = True
    whole["identification"]["impacts_without_cor"] = []
    section = lost_html(whole)
    assert 'id="nothing-lost"' in section and "Nothing lost" in section and "<table" not in section
    assert f"frames without DIC (ball): 0 of {FRAMES}" in section


def test_the_new_sections_name_no_results_key(run):
    """Methods, uncertainty, losses and the D sentence speak words: no results.json key (snake_case) in their text
    (the Reproduce block's quoted command, paths and rig.yaml are the user's and are left out)."""
    _, doc, page, _ = run
    keys = {k for k in keys_of(doc) if "_" in k}
    assert "subset_px" in keys and "rms_floor_mm" in keys   # the provenance's keys are among them
    for section in ("methods", "uncertainty", "lost", "which-d"):
        text = " ".join(page.ids[section].split())
        assert text and not [k for k in keys if re.search(rf"\b{re.escape(k)}\b", text)], section
