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
    assert len(got["after"]) >= 2, got  # numpy's and OpenCV's own OpenBLAS at least
    assert got["after"] == [1] * len(got["after"]), got
    assert got["cv2"] == 1


# Issue 41 item 1: `detect` and the Python API ran with a BLAS thread per core; beside another
# CPU job the demo photo's "measure" took 394-690 ms instead of 90-120 ms with one thread.
PROBE_DURING = """
import json, sys, cv2, threadpoolctl, numpy as np
import lishield_guard.profiles.detect as pipeline

def blas():
    return [i["num_threads"] for i in threadpoolctl.threadpool_info() if i["user_api"] == "blas"]

import scipy.linalg  # loaded up front, so that "before" sees every BLAS library
seen = {"before": blas(), "cv2_before": cv2.getNumThreads()}
inner = pipeline.detect_decoded

def probe(*args, **kwargs):
    seen["during"] = blas()
    seen["cv2_during"] = cv2.getNumThreads()
    return inner(*args, **kwargs)

pipeline.detect_decoded = probe
if sys.argv[1] == "cli":
    from typer.testing import CliRunner
    from lishield_guard.cli import app
    res = CliRunner().invoke(app, ["detect", sys.argv[2], *sys.argv[3:]])
    seen["exit"] = res.exit_code
else:
    import lishield_guard
    lishield_guard.detect(np.random.default_rng(0).integers(0, 255, (256, 256), np.uint8))
seen["after"] = blas()
seen["cv2_after"] = cv2.getNumThreads()
print(json.dumps(seen))
"""


def _probe(*args: str) -> dict:
    env = {"PATH": "/usr/bin:/bin", "OPENBLAS_NUM_THREADS": "2",
           **{k: v for k, v in os.environ.items() if k == "PYTHONPATH"}}
    out = subprocess.run([sys.executable, "-c", PROBE_DURING, *args], capture_output=True,
                         text=True, timeout=300, env=env)
    assert out.returncode == 0, out.stderr
    got = json.loads(out.stdout.strip().splitlines()[-1])
    if (os.cpu_count() or 1) > 1:  # else there was nothing to limit
        assert max(got["before"]) > 1 and got["cv2_before"] > 1, got
    return got


def test_detect_command_runs_with_one_native_thread_or_threads(tmp_path):
    from PIL import Image

    import numpy as np

    img = tmp_path / "x.png"
    Image.fromarray(np.random.default_rng(0).integers(0, 255, (128, 128), np.uint8)).save(img)
    got = _probe("cli", str(img))
    assert got["exit"] == 0, got
    assert got["during"] == [1] * len(got["during"]) and got["cv2_during"] == 1, got
    got = _probe("cli", str(img), "--threads", "2")
    assert got["during"] == [2] * len(got["during"]) and got["cv2_during"] == 2, got


def test_python_api_runs_with_one_native_thread_and_restores_the_callers():
    """The first call of `lishield_guard.detect` in a fresh program is pinned too, and the
    program's own thread counts are back after it."""
    got = _probe("api")
    assert got["during"] == [1] * len(got["during"]) and got["cv2_during"] == 1, got
    assert got["after"] == got["before"] and got["cv2_after"] == got["cv2_before"], got


def test_native_threads_nest_and_refuse_a_bad_count():
    import pytest

    from lishield_guard.errors import ConfigError
    from lishield_guard.threads import native_threads

    with native_threads(1) as n, native_threads(3) as m:  # the first to enter sets it
        assert (n, m) == (1, 1)
    with pytest.raises(ConfigError, match="n_threads"):
        with native_threads(0):
            pass
