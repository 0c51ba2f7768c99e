"""C reference player: built with the system compiler; its edges must equal the Python model's."""

from __future__ import annotations

import dataclasses
import shutil
import subprocess
from pathlib import Path

import pytest

from firmware.emit import to_binary, to_c_header
from firmware.sequence import compile_spec
from lishield_guard.spec import PRESETS

PLAYER_DIR = Path(__file__).resolve().parents[2] / "firmware" / "player"
CFLAGS = ["-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic", "-O1"]
N_LOOPS = 3
RANDOMIZED = dataclasses.replace(PRESETS["table2-rgb"], name="rgb-k4", intensity_levels=4)
CASES = {name: (spec, None) for name, spec in PRESETS.items()}
CASES["rgb-k4"] = (RANDOMIZED, b"player-test-secret")

pytestmark = pytest.mark.skipif(shutil.which("cc") is None, reason="no C compiler (cc)")


def _build(out: Path, *extra: str) -> Path:
    cmd = ["cc", *CFLAGS, *extra, "-o", str(out), str(PLAYER_DIR / "host_test.c"),
           str(PLAYER_DIR / "lishield_player.c")]
    res = subprocess.run(cmd, capture_output=True, text=True, check=False)
    assert res.returncode == 0, res.stderr
    return out


@pytest.fixture(scope="module")
def host_test(tmp_path_factory) -> Path:
    return _build(tmp_path_factory.mktemp("player") / "host_test")


def _run(exe: Path, *args: str) -> list[tuple[int, int, int]]:
    res = subprocess.run([str(exe), *args], capture_output=True, text=True, check=False,
                         timeout=60)
    assert res.returncode == 0, res.stderr
    return [tuple(int(x) for x in ln.split()) for ln in res.stdout.splitlines()]


@pytest.mark.parametrize("name", list(CASES))
def test_c_player_edges_equal_python_edges(host_test, tmp_path, name):
    spec, seed = CASES[name]
    seq = compile_spec(spec, seed=seed)
    path = tmp_path / f"{name}.bin"
    path.write_bytes(to_binary(seq))
    expected = seq.edges(N_LOOPS)
    assert _run(host_test, str(path), str(N_LOOPS)) == expected  # timer-interrupt style
    assert _run(host_test, str(path), str(N_LOOPS), "7") == expected  # tick-advance style
    assert _run(host_test, str(path), str(N_LOOPS), "100000") == expected  # coarse chunks


def test_c_player_with_generated_header(tmp_path):
    seq = compile_spec(RANDOMIZED, seed=b"header-secret")
    (tmp_path / "seq.h").write_text(to_c_header(seq))
    exe = _build(tmp_path / "host_test_h", f"-I{tmp_path}", '-DLSP_SEQUENCE_HEADER="seq.h"')
    assert _run(exe, "2") == seq.edges(2)


def test_c_player_rejects_corrupt_files(host_test, tmp_path):
    data = to_binary(compile_spec(PRESETS["table1-seq1"]))
    for mutated, msg in [(data[:-1], "truncated"), (b"XXXX" + data[4:], "bad magic"),
                         (data[:-5] + bytes([data[-5] ^ 1]) + data[-4:], "CRC mismatch")]:
        path = tmp_path / "bad.bin"
        path.write_bytes(mutated)
        res = subprocess.run([str(host_test), str(path), "1"], capture_output=True, text=True,
                             check=False)
        assert res.returncode == 2 and msg in res.stderr


@pytest.mark.parametrize(("f_b", "phase", "order"), [
    (200.0, "continuous", (2, 0, 1)), (300.0, "continuous", (2, 1, 0)),
    (333.3, "restart", (0, 2, 1))])
def test_c_player_plays_other_emitters_unchanged(host_test, tmp_path, f_b, phase, order):
    import warnings

    spec = dataclasses.replace(PRESETS["table2-rgb"], switching_hz=f_b, phase=phase, order=order)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        seq = compile_spec(spec, clock_hz=16_000_000, allow=("flicker",))
    path = tmp_path / "other.bin"
    path.write_bytes(to_binary(seq))
    assert _run(host_test, str(path), "2") == seq.edges(2)
    header = to_c_header(seq)
    assert f"phase {phase}" in header and ",".join(map(str, order)) in header
