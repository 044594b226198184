"""core.heap: freed memory stays in the heap for reuse (glibc), off on request."""

import os
import subprocess
import sys

import pytest

_PROBE = """
import resource, sys
from vesselid.core.heap import kept_heap
import numpy as np

def faults_of_a_round():
    f0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    arrays = [np.ones(2_500_000) for _ in range(8)]  # 8 x 20 MB, then freed
    del arrays
    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f0

def rss_kb():
    with open("/proc/self/statm") as fh:
        return int(fh.read().split()[1]) * 4

with kept_heap() as on:
    faults_of_a_round()
    inside = faults_of_a_round()
    held = rss_kb()
after = rss_kb()
print(on, inside, held - after)
"""


def _probe(**env: str) -> tuple[bool, int]:
    out = subprocess.run([sys.executable, "-c", _PROBE], capture_output=True, text=True,
                         env={**os.environ, **env}, check=True, timeout=120)
    on, faults, given_back_kb = out.stdout.split()
    return on == "True", int(faults), int(given_back_kb)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc malloc only")
def test_a_second_round_of_large_arrays_reuses_the_heap():
    on, faults, given_back_kb = _probe(VESSELID_KEEP_HEAP="1")
    if not on:
        pytest.skip("not glibc")
    # 160 MB allocated again from the kept heap (40,000 pages): none faults in afresh
    assert faults < 1_000
    # leaving the context gives the kept memory back (most of the 160 MB)
    assert given_back_kb > 100_000
    off, faults_off, _ = _probe(VESSELID_KEEP_HEAP="0")
    assert not off
    # glibc's default gave part of the freed memory back: thousands of pages fault again
    assert faults_off > 2_000
