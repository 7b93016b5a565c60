"""ROS domain ids for tests: private to this test process, and disjoint between pytest-xdist workers.

Each worker owns a band of ids (worker ``gwN`` owns ``BAND * N + 1 ... BAND * (N + 1)``, the main process the
first band) and hands them out in turn, so two tests running at the same time in two workers never share a
domain. The start within the band depends on the process id, so a second test run on this machine (another
checkout) is unlikely to meet this one.
"""

from __future__ import annotations

import itertools
import os

#: ROS 2 domain ids usable with Fast DDS's default ports go to 232: 200 of them shared among the workers
_WORKERS = max(1, int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1")))
BAND = max(1, 200 // _WORKERS)
_WORKER = int(os.environ.get("PYTEST_XDIST_WORKER", "gw0")[2:] or 0) % _WORKERS
_NEXT = itertools.count(os.getpid() % BAND)


def private_domain() -> str:
    """The next domain id of this worker's band, as the string ROS_DOMAIN_ID takes."""
    return str(BAND * _WORKER + 1 + next(_NEXT) % BAND)
