"""A process's own peak resident memory: a child started after its parent's large allocation
reports its own peak, not the parent's (``ru_maxrss`` survives fork + exec on Linux)."""

import json
import subprocess
import sys

import numpy as np
import pytest

from metasensor.io.memory import peak_resident_bytes

# run in a fresh process: in a test worker the peak may already stand above what is allocated
_GROWS = """
import json
import numpy as np
from metasensor.io.memory import peak_resident_bytes as peak
before = peak()
block = np.ones(64 * 2**20 // 8)  # 64 MiB, touched
after = peak()
del block
print(json.dumps([before, after, peak(), float(np.ones(3).sum())]))
"""


def test_the_peak_grows_with_an_allocation_and_stays_after_it_is_freed():
    out = subprocess.run([sys.executable, "-c", _GROWS], capture_output=True, text=True,
                         check=True).stdout
    before, after, freed, _ = json.loads(out.strip().splitlines()[-1])
    assert after >= before + 60 * 2**20, (before, after)
    # freed memory leaves the peak (to within the kernel's batched per-thread counters)
    assert freed >= after - 2**20, (after, freed)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="VmHWM is Linux's")
def test_a_child_reports_its_own_peak_not_its_parents():
    block = np.ones(256 * 2**20 // 8)  # the parent's peak: at least 256 MiB
    assert block.sum() > 0 and peak_resident_bytes() > 256 * 2**20
    code = "from metasensor.io.memory import peak_resident_bytes as p; print(p())"
    child = int(subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                               check=True).stdout.split()[-1])
    assert 0 < child < 200 * 2**20  # numpy and the package, not the parent's 256 MiB


_RESET = """
import json
import numpy as np
from metasensor.io.memory import peak_resident_bytes as peak, reset_peak_resident
block = np.ones(128 * 2**20 // 8)  # 128 MiB, touched
del block
high = peak()
done = reset_peak_resident()
print(json.dumps([high, done, peak()]))
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="clear_refs is Linux's")
def test_a_reset_starts_a_new_peak_at_the_current_resident_memory():
    out = subprocess.run([sys.executable, "-c", _RESET], capture_output=True, text=True,
                         check=True).stdout
    high, done, after = json.loads(out.strip().splitlines()[-1])
    assert done is True
    assert after <= high - 100 * 2**20, (high, after)  # the freed 128 MiB left the peak
