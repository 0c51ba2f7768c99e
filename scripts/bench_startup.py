"""Start-up cost of the command line: wall time of ``--help`` and the import overhead of
``detect`` (everything imported before the first pixel is decoded), median of several runs.

    python scripts/bench_startup.py [--runs 7]

Prints one line per measurement and, for ``detect``, the modules that cost most, so that a
regression names its cause. A benchmark, not a test: the figures depend on the machine.
"""

from __future__ import annotations

import argparse
import io
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

EXE = Path(sys.executable).with_name("lishield-guard")
# what `detect` imports before it decodes: the CLI, the command, the config and the detector
DETECT_IMPORTS = ("import lishield_guard.cli; from lishield_guard.commands.detect import "
                  "resolve_config; resolve_config(None, None); "
                  "from lishield_guard.detector import detect")


def _wall_s(cmd: list[str], runs: int) -> float:
    times = []
    for _ in range(runs):
        t0 = time.perf_counter()
        subprocess.run(cmd, capture_output=True, check=False)
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def _python_s(runs: int) -> float:
    return _wall_s([sys.executable, "-c", "pass"], runs)


def _import_s(code: str, runs: int) -> float:
    """Median in-process time of ``code`` (imports), measured inside a fresh interpreter."""
    prog = f"import time; t0 = time.perf_counter(); {code}; print(time.perf_counter() - t0)"
    vals = []
    for _ in range(runs):
        out = subprocess.run([sys.executable, "-c", prog], capture_output=True, text=True,
                             check=True)
        vals.append(float(out.stdout.strip().splitlines()[-1]))
    return statistics.median(vals)


def _top_imports(code: str, n: int = 8) -> list[tuple[float, str]]:
    """The ``n`` top-level-most expensive imports (cumulative seconds, module)."""
    err = subprocess.run([sys.executable, "-X", "importtime", "-c", code], capture_output=True,
                         text=True, check=True).stderr
    rows = []
    for line in err.splitlines():
        m = re.match(r"import time:\s+\d+ \|\s+(\d+) \| (\s*)(\S+)", line)
        if m and len(m.group(2)) <= 4:  # the first two nesting levels
            rows.append((int(m.group(1)) / 1e6, m.group(3)))
    return sorted(rows, reverse=True)[:n]


def _tiny_png(folder: Path) -> Path:
    import numpy as np
    from PIL import Image

    buf = io.BytesIO()
    rng = np.random.default_rng(0)
    Image.fromarray(rng.integers(0, 256, (80, 80), dtype=np.uint8)).save(buf, "PNG")
    path = folder / "tiny.png"
    path.write_bytes(buf.getvalue())
    return path


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=7, help="runs per measurement (median)")
    args = ap.parse_args(argv)
    runs = args.runs
    python_s = _python_s(runs)
    help_s = _wall_s([str(EXE), "--help"], runs)
    detect_help_s = _wall_s([str(EXE), "detect", "--help"], runs)
    cli_import_s = _import_s("import lishield_guard.cli", runs)
    detect_import_s = _import_s(DETECT_IMPORTS, runs)
    with tempfile.TemporaryDirectory() as tmp:
        tiny = _tiny_png(Path(tmp))
        detect_s = _wall_s([str(EXE), "detect", str(tiny)], runs)
    print(f"python -c pass (interpreter alone)      {python_s:.3f} s")
    print(f"lishield-guard --help                   {help_s:.3f} s wall "
          f"({help_s - python_s:.3f} s over the interpreter)")
    print(f"lishield-guard detect --help            {detect_help_s:.3f} s wall")
    print(f"import lishield_guard.cli               {cli_import_s:.3f} s")
    print(f"detect's imports before decoding        {detect_import_s:.3f} s "
          f"(CLI, config, detector)")
    print(f"lishield-guard detect tiny.png (80x80)  {detect_s:.3f} s wall")
    print("most expensive imports of detect (cumulative s):")
    for sec, mod in _top_imports(DETECT_IMPORTS):
        print(f"  {sec:.3f}  {mod}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
