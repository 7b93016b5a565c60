"""The friction correction travels from the discrepancy node to ``vibro results`` (issue 39: every path gives the
same answer). Measured by hand on a graph run of a rig declared at 45 deg whose axis is at 50 deg: the bag's
flights' friction_n equal analyze's, both corrected for the tilt. Here: the /diagnostics value read back, and a
damaged one said, not read as no correction."""

from __future__ import annotations

import json
from dataclasses import asdict
from types import SimpleNamespace

from vibro_app.bag_results import BagResults
from vibro_model.assemble import FrictionCorrection
from vibro_ros import topics


def _status(value: str):
    kv = [SimpleNamespace(key=topics.FRICTION_CORRECTION_KEY, value=value)]
    return SimpleNamespace(name="/vibro_r1/discrepancy", values=kv)


def _bag() -> BagResults:
    r = BagResults.__new__(BagResults)   # the /diagnostics bookkeeping only, no bag read
    r.friction, r.friction_problem, r.local_structure, r.local_structure_problem = None, "", [], ""
    r.discrepancy, r.discrepancy_problem = None, ""
    return r


def test_the_nodes_friction_correction_is_read_back():
    corr = FrictionCorrection(effect="gravity_tilt", force_n=1.15e-4, force_std_n=2e-9, words="the tilt's force")
    r = _bag()
    r._note_discrepancy_node(_status(json.dumps(asdict(corr))))
    assert r.friction == corr and r.friction_problem == ""


def test_a_damaged_value_is_said_not_taken_for_none():
    r = _bag()
    r._note_discrepancy_node(_status('{"effect": "gravity_tilt"}'))
    assert r.friction is None and topics.FRICTION_CORRECTION_KEY in r.friction_problem
