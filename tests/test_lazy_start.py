"""Issue #33 item 7: the command line starts without numpy, scipy, OpenCV or the detector
(measured by scripts/bench_startup.py; this test guards the cause, not a time)."""

from __future__ import annotations

import subprocess
import sys

HEAVY = ("numpy", "scipy", "cv2", "PIL", "matplotlib", "lishield_guard.detector")


def test_cli_and_package_import_no_heavy_library():
    code = ("import sys, lishield_guard, lishield_guard.cli; "
            f"print([m for m in {HEAVY!r} if m in sys.modules])")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True)
    assert out.stdout.strip() == "[]", out.stdout + out.stderr


def test_help_imports_no_heavy_library():
    code = ("import sys\nfrom lishield_guard.cli import app\n"
            "try:\n    app(['--help'])\nexcept SystemExit:\n    pass\n"
            f"print([m for m in {HEAVY!r} if m in sys.modules], file=sys.stderr)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True)
    assert out.stderr.strip().splitlines()[-1] == "[]", out.stderr


def test_lazy_names_resolve():
    import lishield_guard

    for name in lishield_guard.__all__:
        assert getattr(lishield_guard, name) is not None
    assert callable(lishield_guard.decode) and callable(lishield_guard.detect)
