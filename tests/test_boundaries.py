"""The core must not pull in the web stack, synth or firmware at import time."""

from __future__ import annotations

import subprocess
import sys


def test_core_import_is_light():
    code = ("import sys, lishield_guard, lishield_guard.cli; "
            "bad = [m for m in ('fastapi', 'uvicorn', 'synth', 'firmware', 'service', 'dask') "
            "if m in sys.modules]; print(bad); sys.exit(1 if bad else 0)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0, out.stdout + out.stderr


def test_every_module_has_a_docstring():
    import importlib
    import pkgutil

    import lishield_guard

    missing = []
    for info in pkgutil.walk_packages(lishield_guard.__path__, "lishield_guard."):
        mod = importlib.import_module(info.name)
        if not (mod.__doc__ or "").strip():
            missing.append(info.name)
    assert not missing
