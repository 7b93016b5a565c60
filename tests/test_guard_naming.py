"""When a stopping node may name the publishers of the topic it refused (vibro_ros.guard.naming_settled).

A CI run on a loaded machine stopped the tracker on a foreign camera's frame and named only frame_source:
the foreign endpoint (and its frame) had arrived, its node's name had not, 1 s later. The rule: never name
while a discovered publisher is still unnamed, unless the longest wait has passed.
"""

from __future__ import annotations

import pytest

from vibro_ros.guard import naming_settled

WAIT_S, WAIT_MAX_S = 1.0, 10.0


@pytest.mark.parametrize("waited_s", [0.0, 1.0, 5.0, 9.9])
def test_an_unnamed_publisher_is_waited_for(waited_s: float) -> None:
    assert not naming_settled(1, 1, 1, waited_s, WAIT_S, WAIT_MAX_S)
    assert not naming_settled(1, 2, 1, waited_s, WAIT_S, WAIT_MAX_S)  # one more named, yet another unnamed


def test_the_longest_wait_ends_it_even_with_an_unnamed_publisher() -> None:
    assert naming_settled(1, 1, 1, WAIT_MAX_S, WAIT_S, WAIT_MAX_S)


def test_a_newly_named_publisher_ends_it_at_once() -> None:
    assert naming_settled(1, 2, 0, 0.1, WAIT_S, WAIT_MAX_S)


def test_with_every_publisher_named_it_ends_after_the_short_wait() -> None:
    """The offender may be the expected publisher itself (a wrong time origin): nothing new will be named."""
    assert not naming_settled(1, 1, 0, 0.5, WAIT_S, WAIT_MAX_S)
    assert naming_settled(1, 1, 0, WAIT_S, WAIT_S, WAIT_MAX_S)
