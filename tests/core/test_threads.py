"""Worker processes run one BLAS and one OpenCV thread after `one_thread_per_worker`."""

from __future__ import annotations

import json
import os
import subprocess
import sys

PROBE = """
import json, cv2, threadpoolctl
from lishield_guard.threads import one_thread_per_worker
before = [i["num_threads"] for i in threadpoolctl.threadpool_info() if i["user_api"] == "blas"]
one_thread_per_worker()
one_thread_per_worker()  # a second call (a pool initializer per chunk) changes nothing
after = [i["num_threads"] for i in threadpoolctl.threadpool_info() if i["user_api"] == "blas"]
print(json.dumps({"before": before, "after": after, "cv2": cv2.getNumThreads()}))
"""


def test_one_thread_per_worker_limits_every_loaded_blas_and_opencv():
    """In a fresh interpreter (the suite's own process is already limited): numpy's and
    scipy's BLAS libraries, whichever were loaded, end at one thread, and OpenCV at one."""
    out = subprocess.run([sys.executable, "-c", PROBE], capture_output=True, text=True,
                         timeout=120, env={"PATH": "/usr/bin:/bin", "OPENBLAS_NUM_THREADS": "2"})
    assert out.returncode == 0, out.stderr
    got = json.loads(out.stdout.strip().splitlines()[-1])
    if (os.cpu_count() or 1) > 1:  # else there was nothing to limit
        assert max(got["before"]) > 1, got
    assert len(got["after"]) >= 2, got  # numpy's and scipy's own OpenBLAS at least
    assert got["after"] == [1] * len(got["after"]), got
    assert got["cv2"] == 1
