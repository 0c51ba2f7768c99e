"""One type table: every image type `scan` reads, `calibrate` and `bench` read too."""

from __future__ import annotations

import io

import numpy as np
import pytest
from PIL import Image

from lishield_guard import bench, calibration
from lishield_guard.batch import IMAGE, KINDS, kind_of_bytes, kind_of_name, list_files
from lishield_guard.scan import iter_items


def _jpeg() -> bytes:
    buf = io.BytesIO()
    Image.fromarray(np.zeros((8, 8, 3), np.uint8)).save(buf, "JPEG")
    return buf.getvalue()


@pytest.fixture
def every_type(tmp_path):
    """One file per suffix of the table (and upper case), an image without a suffix, and
    files no tool reads (notes, a manifest, an AppleDouble sidecar)."""
    data = _jpeg()  # the bytes do not matter to a lister that goes by name
    names = [f"a{s}" for s in IMAGE.suffixes] + [f"B{s.upper()}" for s in IMAGE.suffixes]
    sub = tmp_path / "sub"
    sub.mkdir()
    for i, name in enumerate(names):
        ((sub if i % 2 else tmp_path) / name).write_bytes(data)
    (tmp_path / "no_suffix").write_bytes(data)
    (tmp_path / "notes.txt").write_text("not an image")
    (tmp_path / "manifest.jsonl").write_text("")
    (tmp_path / "._a.jpg").write_bytes(b"\x00\x05\x16\x07 AppleDouble")
    return tmp_path, len(names) + 1


def test_calibrate_and_bench_read_every_type_scan_reads(every_type):
    folder, n = every_type
    scanned = sorted(item.label for item in iter_items([str(folder)], read_data=False))
    assert len(scanned) == n
    listed = [str(p) for p in list_files(folder)]
    assert sorted(listed) == scanned
    assert [str(p) for p, _ in calibration.list_images(folder)] == listed
    assert [str(it.path) for it in bench.clean_items(folder)] == listed


def test_listing_is_sorted_like_rglob(every_type):
    folder, _ = every_type
    listed = list_files(folder)
    assert listed == sorted(listed)


@pytest.mark.parametrize("suffix", [".gif", ".jpe", ".jfif", ".JPG", ".heic"])
def test_the_table_knows_the_names(suffix):
    assert kind_of_name(f"x{suffix}") is IMAGE


def test_signatures_and_kinds():
    assert kind_of_bytes(_jpeg()[:32]) is IMAGE
    assert kind_of_bytes(b"# notes") is None
    assert kind_of_name("clip.txt") is None
    assert IMAGE in KINDS
    assert all(k.suffixes and k.media_types for k in KINDS)


def test_the_service_declares_the_types_of_the_table():
    pytest.importorskip("fastapi")
    from service.routes import screen

    assert screen.IMAGE_MEDIA_TYPES == IMAGE.media_types
