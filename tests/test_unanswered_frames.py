"""A frame slot the graph never tracked makes the run incomplete for the end-of-run judges (issue 39): the
simulator computes no D and the discrepancy node no findings over part of a run (vibro_ros.fit_results)."""

from __future__ import annotations

from types import SimpleNamespace

from vibro_ros.fit_results import FinalFitResults


def _results(indices, reference=0):
    r = FinalFitResults.__new__(FinalFitResults)   # the bookkeeping only: no node, no subscriptions
    r.frames = {k: SimpleNamespace(frame_index=k, reference_frame_index=reference, lost=k % 7 == 0) for k in indices}
    return r


def test_every_slot_answered_lost_or_not_is_complete():
    r = _results(range(0, 300))          # every 7th frame lost (answered as lost): still complete
    assert r.unanswered_frames() == [] and r.incomplete_words() == ""


def test_slots_never_answered_are_named():
    r = _results([*range(0, 100), *range(132, 300)])   # a killed tracker: 32 slots without any DicFrame
    assert r.unanswered_frames() == list(range(100, 132))
    words = r.incomplete_words()
    assert "32 frame slot(s) without any DIC result (100..131)" in words and "not judged" in words


def test_the_reference_frame_starts_the_count():
    r = _results(range(50, 120), reference=50)          # a run tracked from frame 50 on
    assert r.unanswered_frames() == []
