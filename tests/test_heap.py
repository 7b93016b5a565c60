"""vibro_model.heap.steady_heap: a loop that allocates and frees the same megabytes each iteration reuses them
instead of faulting fresh pages in every time (the synthetic camera's frames: docs in the module)."""

from __future__ import annotations

import subprocess
import sys

#: 400 iterations each making, touching and dropping three arrays of 1-6 MiB (a synthetic frame's spectra are
#: ~1 MB each); prints whether the thresholds were set and the loop's minor page faults per iteration
LOOP = """
import resource, sys
import numpy as np
from vibro_model.heap import steady_heap
ok = steady_heap() if sys.argv[1] == "steady" else True
def iteration(k):
    a = np.ones((k % 6 + 1) << 17)               # 1..6 MiB of float64, every page written
    b = a * 2.0
    c = a + b
    del a, b, c
for k in range(12):
    iteration(k)                                 # warm: every size made once
f0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for k in range(400):
    iteration(k)
print(ok, (resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f0) / 400)
"""


def _faults_per_iteration(mode: str) -> tuple[bool, float]:
    out = subprocess.run([sys.executable, "-c", LOOP, mode], capture_output=True, text=True, timeout=120, check=True)
    ok, faults = out.stdout.split()
    return ok == "True", float(faults)


def test_a_loop_of_megabyte_arrays_reuses_its_memory() -> None:
    # the premise: with glibc's moving thresholds this loop gives its memory back and faults it in again (each
    # iteration writes 6-36 MiB = 1536-9216 pages; measured ~960 faults per iteration)
    _, churn = _faults_per_iteration("plain")
    assert churn > 100, churn
    ok, faults = _faults_per_iteration("steady")
    assert ok, "mallopt refused the thresholds (glibc expected on this project's machines)"
    # reused memory faults none of those pages again (a few for Python's own small allocations)
    assert faults < 16, f"{faults:.0f} minor page faults per iteration: freed memory was given back and re-faulted"
