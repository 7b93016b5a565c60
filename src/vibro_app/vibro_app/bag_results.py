"""``vibro results <bag>``: the results.json of a recorded graph run, rebuilt from its messages.

The messages become model types through :mod:`vibro_ros.convert` and the document is written by the one
codec (:mod:`vibro_model.codec`), so a graph run's document has the keys and meanings of
``vibro analyze``'s: flights' ``t_start``/``t_end`` are the impacts that open/close them (the first/last
fitted frame in ``t_first_frame``/``t_last_frame``), ``free`` says whether a flight is free,
``cor_statistics`` is computed from the impacts as analyze does. The impacts the discrepancy node measured
again under its final model (vibro/impacts_final_model) replace the fitter's, which stay beside them as
``cor_paper``/``t_paper`` (:mod:`vibro_discrepancy.reidentify`, as analyze does). ``ball_spin`` is
analyze's section (:func:`vibro_fit.spin.ball_spin_section`) of the recorded DicFrames' ball rotation and the
final flights and impacts; a bag recorded before DicFrame carried the rotation has no ``ball_spin`` and a
warning saying why.

Flights and impacts marked ``final`` (the fitter's end-of-stream pass) replace the streamed previews with
the same index. A bag is complete when every stream the fitter, simulator and discrepancy node announced
finished (vibro/status) has all its items in the bag; otherwise (the recorder was killed, a node died)
the document keeps what there is (streamed estimates where no final one arrived), says
``"complete": false`` with a warning naming what is missing, and ``vibro results`` exits 1.

The fitter runs ``vibro analyze``'s cross-checks (:func:`vibro_fit.cross_checks.consistency_checks`) in its final
pass and carries them on its /diagnostics status (values ``consistency``: the section's JSON, ``refused``: the
refusal line; :data:`vibro_ros.topics.CONSISTENCY_KEY`), which the bag records: the document gets analyze's
``consistency`` section. A refused run (the fitter published no final impact, ended its impacts stream with them
counted lost and exited with code 2) gives analyze's refused document: no COR table (streamed previews
dropped too), ``"complete": false``, and ``vibro results`` exits 2 with the refusal in one line.
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path

from vibro_app.findings_text import findings_lines
from vibro_app.run_completeness import RunCompleteness, restarts_from_pids, run_completeness
from vibro_fit.plausibility import consistency_stage, findings_from_section
from vibro_fit.spin import ball_spin_section
from vibro_io.outputs import atomic_write_text, prepare_output_dir, prepare_output_file
from vibro_io.results_file import RESULTS_JSON
from vibro_model.assemble import (
    BallSpinStage,
    CompletenessStage,
    ConsistencyStage,
    DiscrepancyStage,
    FrictionCorrection,
    Identified,
    LocalStructure,
    Reidentification,
    SimulationStage,
    StageOutputs,
    assemble_results,
)
from vibro_model.codec import ResultsError
from vibro_model.results import Discrepancy, ResultsDocument, Simulation, results_text
from vibro_ros import topics
from vibro_ros.bags import deserialize, make_typestore, read_messages
from vibro_ros.convert import (
    carries_ball_rotation,
    dic_track_from_messages,
    finding_from_message,
    flight_from_message,
    impact_from_message,
    simulation_run_from_message,
    structure_from_message,
    structure_sections,
)

#: end-of-stream statuses a complete graph run has, and the result topic each one counts
EXPECTED_STREAMS = {"flights": topics.FLIGHTS.name, "impacts": topics.IMPACTS.name,
                    "simulation": topics.SIMULATION.name, "discrepancy": topics.DISCREPANCY.name}
#: the discrepancy node's stream of impacts re-measured under its final model (not in bags recorded before it)
FINAL_MODEL_STREAM = "impacts_final_model"


class BagResults:
    """The result messages of one bag, sorted out: latest per index, finals apart from streamed previews."""

    def __init__(self, bag: str | Path):
        self.bag = str(bag)
        self.structure = None
        self.streamed: dict[str, dict[int, object]] = {topics.FLIGHTS.name: {}, topics.IMPACTS.name: {}}
        self.final: dict[str, dict[int, object]] = {topics.FLIGHTS.name: {}, topics.IMPACTS.name: {}}
        self.simulation: dict[str, object] = {}
        self.findings: dict[int, object] = {}
        self.final_model: dict[int, object] = {}  # vibro/impacts_final_model by index
        self.finished: dict[str, int] = {}  # stream -> items the node announced at its end
        self.finished_lost: dict[str, int] = {}  # stream -> items it announced lost at its end
        self.frames: list = []  # vibro/dic, as recorded
        self.pids: dict[str, set[str]] = {}  # node name -> process ids its /diagnostics carried (restarts)
        self.consistency: dict | None = None  # the fitter's cross-checks (its /diagnostics, topics.CONSISTENCY_KEY)
        self.refused = ""  # the fitter's refusal line (topics.REFUSED_KEY), "" when it published its results
        self.consistency_problem = ""  # why a recorded consistency value could not be read
        self.local_structure: list[LocalStructure] = []  # the discrepancy node's (topics.LOCAL_STRUCTURE_KEY)
        self.local_structure_problem = ""  # why a recorded local_structure value could not be read
        self.friction: FrictionCorrection | None = None  # the discrepancy node's (topics.FRICTION_CORRECTION_KEY)
        self.friction_problem = ""  # why a recorded friction_correction value could not be read
        self.discrepancy: Discrepancy | None = None  # the discrepancy node's section (topics.DISCREPANCY_KEY)
        self.discrepancy_problem = ""  # why a recorded discrepancy value could not be read
        store = make_typestore()
        wanted = {topics.STRUCTURE.name, topics.FLIGHTS.name, topics.IMPACTS.name, topics.SIMULATION.name,
                  topics.DISCREPANCY.name, topics.IMPACTS_FINAL_MODEL.name, topics.STATUS.name, topics.DIC.name,
                  topics.DIAGNOSTICS.name}
        for m in read_messages(bag, wanted):
            msg = deserialize(m, store)
            if m.topic == topics.DIAGNOSTICS.name:
                for status in msg.status:
                    pid = next((kv.value for kv in status.values if kv.key == "pid"), None)
                    if pid is not None:
                        self.pids.setdefault(str(status.name).rsplit("/", 1)[-1], set()).add(str(pid))
                    self._note_consistency(status)
                    self._note_discrepancy_node(status)
            elif m.topic == topics.DIC.name:
                self.frames.append(msg)
            elif m.topic == topics.STRUCTURE.name:
                self.structure = msg
            elif m.topic in self.final:
                (self.final if msg.final else self.streamed)[m.topic][int(msg.index)] = msg
            elif m.topic == topics.SIMULATION.name:
                self.simulation[str(msg.model)] = msg
            elif m.topic == topics.DISCREPANCY.name:
                self.findings[int(msg.index)] = msg
            elif m.topic == topics.IMPACTS_FINAL_MODEL.name:
                self.final_model[int(msg.index)] = msg
            elif msg.finished:
                self.finished[str(msg.stream)] = int(msg.items_sent)
                self.finished_lost[str(msg.stream)] = int(msg.items_lost)

    def _note_consistency(self, status) -> None:
        """The trajectory_fitter's cross-checks and refusal, carried by its /diagnostics status once its final
        pass ran (the latest wins)."""
        if str(status.name).rsplit("/", 1)[-1] != "trajectory_fitter":
            return
        values = {kv.key: kv.value for kv in status.values}
        if topics.CONSISTENCY_KEY in values:
            try:
                section = json.loads(values[topics.CONSISTENCY_KEY])
            except ValueError as exc:
                section = exc
            if isinstance(section, dict) and isinstance(section.get("findings", []), list) \
                    and all(isinstance(f, dict) for f in section.get("findings", [])):
                self.consistency, self.consistency_problem = section, ""
            else:  # not vibro's section: said, never read as "no finding"
                self.consistency = None
                self.consistency_problem = (f"the trajectory_fitter's /diagnostics value '{topics.CONSISTENCY_KEY}' "
                                            f"is not a consistency section ({str(section)[:80]}); its cross-checks "
                                            "are not in this document")
        if values.get(topics.REFUSED_KEY):
            self.refused = values[topics.REFUSED_KEY]

    def _note_discrepancy_node(self, status) -> None:
        """What the discrepancy node's /diagnostics status carries once it ran (the latest wins): results.json's
        ``discrepancy`` section as it computed it, and the impacts it measured with a local structure velocity.
        A value that does not read is said in a warning, never read as nothing to report."""
        if str(status.name).rsplit("/", 1)[-1] != "discrepancy":
            return
        values = {kv.key: kv.value for kv in status.values}
        if topics.DISCREPANCY_KEY in values:
            where = f"the discrepancy node's /diagnostics value '{topics.DISCREPANCY_KEY}'"
            try:
                self.discrepancy = Discrepancy.from_dict(json.loads(values[topics.DISCREPANCY_KEY]), where)
                self.discrepancy_problem = ""
            except (ValueError, ResultsError) as exc:
                self.discrepancy = None
                self.discrepancy_problem = (f"{where} could not be read ({exc}); the discrepancy section holds the "
                                            "findings published as messages only")
        if values.get(topics.FRICTION_CORRECTION_KEY):
            self._note_friction(values[topics.FRICTION_CORRECTION_KEY])
        if topics.LOCAL_STRUCTURE_KEY in values:
            try:
                self.local_structure = [LocalStructure(**{k: float(v) for k, v in entry.items()})
                                        for entry in json.loads(values[topics.LOCAL_STRUCTURE_KEY])]
                self.local_structure_problem = ""
            except (ValueError, TypeError, AttributeError) as exc:
                self.local_structure = []
                self.local_structure_problem = (f"the discrepancy node's /diagnostics value "
                                                f"'{topics.LOCAL_STRUCTURE_KEY}' could not be read ({exc}); which "
                                                "impacts took a local structure velocity is not in this document")

    def _note_friction(self, text: str) -> None:
        """The friction correction the discrepancy node applied (a mapping of FrictionCorrection's fields); one that
        does not read is said in a warning (the flights then keep their Eq. 17 friction)."""
        try:
            entry = json.loads(text)
            self.friction = FrictionCorrection(effect=str(entry["effect"]), force_n=float(entry["force_n"]),
                                               force_std_n=float(entry["force_std_n"]),
                                               words=str(entry.get("words", "")))
            self.friction_problem = ""
        except (ValueError, TypeError, KeyError, AttributeError) as exc:
            self.friction = None
            self.friction_problem = (f"the discrepancy node's /diagnostics value "
                                     f"'{topics.FRICTION_CORRECTION_KEY}' could not be read ({exc}); the "
                                     "flights keep their Eq. 17 friction")

    def received(self, stream: str) -> int:
        topic = EXPECTED_STREAMS[stream]
        if topic in self.final:
            return len(self.final[topic])
        return len(self.simulation) if stream == "simulation" else len(self.findings)

    def missing(self) -> list[str]:
        """What a complete run would hold and this bag does not, in plain words (empty: complete)."""
        out = []
        if self.structure is None:
            out.append(f"no {topics.STRUCTURE.name} message (the fitter's final pass)")
        for stream, topic in EXPECTED_STREAMS.items():
            if stream not in self.finished:
                out.append(f"no end-of-stream status '{stream}'")
            elif self.received(stream) < self.finished[stream]:
                out.append(f"{self.received(stream)} of the {self.finished[stream]} announced {topic} messages")
            if stream in ("flights", "impacts") and self.finished_lost.get(stream, 0) > 0:  # a refused fit withholds
                out.append(f"{self.finished_lost[stream]} {topic} message(s) announced lost by their publisher")
        # optional: a bag recorded before the discrepancy node re-measured impacts has no such status
        announced = self.finished.get(FINAL_MODEL_STREAM)
        if announced is not None and len(self.final_model) < announced:
            out.append(f"{len(self.final_model)} of the {announced} announced {topics.IMPACTS_FINAL_MODEL.name} "
                       "messages")
        return out

    def completeness(self, impacts: int) -> RunCompleteness:
        """Frame slots without a DicFrame, the impacts they may hide, and restarts (:mod:`vibro_app.run_completeness`);
        the slots expected are those the frame source announced at its end (sent + unreadable)."""
        answered = {int(m.frame_index): float(m.t_s) for m in self.frames}
        first = min((int(m.reference_frame_index) for m in self.frames), default=0)
        expected = (self.finished["frames"] + self.finished_lost.get("frames", 0)) if "frames" in self.finished \
            else None
        return run_completeness(answered, expected, first, impacts=impacts, restarts=restarts_from_pids(self.pids),
                                source_lost=self.finished_lost.get("frames", 0))

    def merged(self, topic: str) -> list:
        """The final messages when the fitter's final pass is in the bag whole (its end-of-stream status announced
        them all); otherwise the final messages and the streamed preview of every index without a final one.
        A preview is never kept beside a complete final pass: the final identification may number its flights and
        impacts differently (hops measured as a chain, landings), and a preview at an index it does not use is
        not a result."""
        stream = {topics.FLIGHTS.name: "flights", topics.IMPACTS.name: "impacts"}[topic]
        announced = self.finished.get(stream)
        if announced is not None and len(self.final[topic]) >= announced and (announced or not self.streamed[topic]
                                                                              or self.structure is not None):
            return list(self.final[topic].values())
        return list({**self.streamed[topic], **self.final[topic]}.values())


def ball_spin_from_frames(frames: list, flights: list, impacts: list) -> tuple[dict | None, str]:
    """``vibro analyze``'s ``ball_spin`` section (:func:`vibro_fit.spin.ball_spin_section`) of DicFrame messages
    (rclpy or decoded from a bag) and the final flights and impacts (model types); (None, the reason) when the
    frames carry no ball rotation at all (none recorded, or a bag recorded before DicFrame had it)."""
    if not frames:
        return None, f"no {topics.DIC.name} message in the bag, so no ball rotation"
    if not all(carries_ball_rotation(m) for m in frames):
        return None, (f"the bag's {topics.DIC.name} messages have no ball_rot_rad field (recorded before DicFrame "
                      "carried the ball rotation); track the recording again (vibro analyze or vibro replay)")
    return ball_spin_section(dic_track_from_messages(frames), flights, impacts), ""


def document_from_bag(bag: str | Path) -> ResultsDocument:
    """The results document of a recorded graph run (``complete`` False when the bag is not whole), assembled
    by the one assembler (:func:`vibro_model.assemble.assemble_results`) from the stage outputs the bag's
    messages carry."""
    r = BagResults(bag)
    stages = bag_stages(r)
    final = assemble_results(stages)
    return assemble_results(replace(stages, ball_spin=_ball_spin_stage(r.frames, final)))


def bag_stages(r: BagResults) -> StageOutputs:
    """The stage outputs of a recorded graph run: the fitter's final (or streamed) structure, flights and
    impacts, what the run lost, the fitter's cross-checks, the simulator's runs, the discrepancy node's
    findings and the impacts it re-measured under its final model."""
    from vibro_discrepancy.reidentify import measurement_effects, reidentified_from_impacts

    impacts = [impact_from_message(m) for m in r.merged(topics.IMPACTS.name)]
    flights = [flight_from_message(m) for m in r.merged(topics.FLIGHTS.name)]
    structure = None if r.structure is None else structure_from_message(r.structure)
    identified = Identified(structure=structure, flights=flights, impacts=impacts,
                            sections={} if r.structure is None else structure_sections(r.structure))
    findings = [finding_from_message(r.findings[k]) for k in sorted(r.findings)]
    remeasured = [impact_from_message(r.final_model[k]) for k in sorted(r.final_model)]
    identified_doc = assemble_results(StageOutputs(recording=r.bag, identified=identified))
    redo = Reidentification(effects=tuple(measurement_effects(findings)),
                            impacts=reidentified_from_impacts(identified_doc, remeasured),
                            local_structure=r.local_structure, friction=r.friction)
    return StageOutputs(
        recording=r.bag, identified=identified, completeness=_completeness_stage(r, len(impacts)),
        consistency=_consistency_stage(r),
        simulation=SimulationStage(simulation=Simulation({name: simulation_run_from_message(m)
                                                          for name, m in r.simulation.items()})),
        discrepancy=_discrepancy_stage(r, findings, redo))


def _completeness_stage(r: BagResults, impacts: int) -> CompletenessStage:
    """What the run lost: streams cut short (the bag's end-of-stream statuses) and frame slots without DIC."""
    missing = r.missing()
    completeness = r.completeness(impacts)
    warnings = []
    if missing:
        warnings.append(f"bag cut short: {'; '.join(missing)}; flights and impacts without a final estimate are "
                        "the streamed ones")
    return CompletenessStage(section=completeness.to_dict(), warnings=warnings + completeness.warnings(),
                             complete=not missing and not completeness.lost_anything)


def _consistency_stage(r: BagResults) -> ConsistencyStage | None:
    """The fitter's cross-checks and refusal as its /diagnostics carried them (None: none recorded)."""
    if r.consistency is None and not r.refused:
        return ConsistencyStage(section=None, problem=r.consistency_problem) if r.consistency_problem else None
    section = dict(r.consistency or {"findings": [], "checks": {}})
    section["refused"] = bool(r.refused) or bool(section.get("refused"))
    return consistency_stage(findings_from_section(section), section, refused_line=r.refused,
                             problem=r.consistency_problem)


def _discrepancy_stage(r: BagResults, findings: list, redo: Reidentification) -> DiscrepancyStage:
    """The discrepancy node's findings (D before the first and after the last), and the impacts it re-measured."""
    warnings = [w for w in (r.local_structure_problem, r.discrepancy_problem, r.friction_problem) if w]
    if r.discrepancy is not None and len(r.discrepancy.findings) == len(findings):
        # the node's own section: the baseline D and the engine's details beside the findings it published
        return DiscrepancyStage(discrepancy=r.discrepancy, warnings=warnings, reidentification=redo)
    if "discrepancy" in r.finished and not findings:
        # a bag recorded before the node carried its section on /diagnostics: findings only, no baseline D
        warnings.append("discrepancy: no finding published and no discrepancy section on the node's /diagnostics "
                        "(a bag recorded before it carried one); the baseline D is not recorded (baseline_deviation "
                        "and final_deviation are null)")
    discrepancy = Discrepancy(findings[0].deviation_before if findings else None, findings,
                              findings[-1].deviation_after if findings else None)
    return DiscrepancyStage(discrepancy=discrepancy, warnings=warnings, reidentification=redo)


def _ball_spin_stage(frames: list, final: ResultsDocument) -> BallSpinStage:
    """The ``ball_spin`` section (as ``vibro analyze``'s) of the recorded DicFrames and the final flights and
    impacts."""
    section, why_not = ball_spin_from_frames(frames, final.flights, final.impacts)
    return BallSpinStage(section=section, why_not=why_not)


def results_from_bag(bag: str | Path) -> dict:
    """The results.json mapping of a recorded graph run (see :func:`document_from_bag`)."""
    return document_from_bag(bag).to_dict()


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("results", help="extract results.json from a recorded graph bag")
    p.add_argument("bag", help="bag directory (rosbag2, MCAP storage)")
    p.add_argument("--out", help="write results.json into this folder (created; must be empty unless "
                                 "--overwrite), or to this file if the name ends in .json (default: print it)")
    p.add_argument("--overwrite", action="store_true",
                   help="replace the results.json of an earlier 'vibro results' in --out")
    p.set_defaults(func=run)


def prepare_results_path(out: str | Path, overwrite: bool, inputs: list[Path]) -> Path:
    """Where ``vibro results --out OUT`` writes: OUT itself if it ends in .json, else OUT/results.json
    (OUT prepared by :func:`vibro_io.outputs.prepare_output_dir`)."""
    out = Path(out)
    if out.suffix == ".json":
        return prepare_output_file(out, overwrite=overwrite)
    prepare_output_dir(out, overwrite=overwrite, owned=(RESULTS_JSON,), command="results", inputs=inputs)
    return out / RESULTS_JSON


def run(args: argparse.Namespace) -> int:
    doc = document_from_bag(args.bag)
    text = results_text(doc)
    if args.out:
        bag = Path(args.bag)  # the bag and its graph logs may sit in --out: inputs, kept
        out = prepare_results_path(args.out, args.overwrite, [bag, bag.parent / f"{bag.name}.logs"])
        atomic_write_text(out, text)
        print(f"wrote {out}")
        stream = sys.stdout
    else:
        print(text, end="")
        stream = sys.stderr  # stdout holds the JSON document

    consistency = doc.sections.get("consistency") or {}
    if doc.complete:  # a refused run never reached the discrepancy analysis; an incomplete one is not judged
        for line in findings_lines(json.loads(text).get("discrepancy")):
            print(line, file=stream)
    if consistency.get("refused"):
        print(f"vibro results: error: {args.bag}: the run was refused: {doc.warnings[0].removeprefix('refused: ')}; "
              "the document has no COR table (see its 'consistency' section) and is marked \"complete\": false",
              file=sys.stderr)
        return 2
    if not doc.complete:
        print(f"vibro results: error: {args.bag}: the run in this bag is incomplete ({doc.warnings[0]}); "
              "the document is marked \"complete\": false", file=sys.stderr)
        return 1
    return 0
