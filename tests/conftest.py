"""Suite-wide set-up: the test process runs one BLAS and OpenCV thread, as every worker does."""

from __future__ import annotations


def pytest_configure(config) -> None:
    """Limit native thread pools once, before any test runs (results do not depend on it;
    idle BLAS threads busy-waiting beside the suite's worker processes only waste cores)."""
    from lishield_guard.threads import one_thread_per_worker

    one_thread_per_worker()
