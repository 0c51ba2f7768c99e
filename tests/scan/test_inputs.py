"""Input enumeration: folders, lists, filters, and archives read in memory with hostile members."""

from __future__ import annotations

import io
import tarfile
import zipfile
from pathlib import Path

from scan_helpers import jpeg_bytes, read_jsonl, write_images

from lishield_guard.scan import iter_items, unsafe_member_reason


def _labels(paths, **kw) -> list[str]:
    return [it.label for it in iter_items([str(p) for p in paths], **kw)]


def test_folder_walk_is_recursive_and_sorted(tmp_path):
    write_images(tmp_path, ["b.jpg", "a/z.jpg", "a/b/c.jpg", "c.png"])
    labels = _labels([tmp_path])
    rel = [Path(x).relative_to(tmp_path).as_posix() for x in labels]
    assert rel == ["a/b/c.jpg", "a/z.jpg", "b.jpg", "c.png"]
    assert labels == _labels([tmp_path])  # deterministic


def test_include_exclude(tmp_path):
    write_images(tmp_path, ["a.jpg", "b.png", "skip/c.jpg", "d.JPG"])
    rel = {Path(x).relative_to(tmp_path).as_posix()
           for x in _labels([tmp_path], include=["*.jpg"], exclude=["skip"])}
    assert rel == {"a.jpg", "d.JPG"}  # globs are case-insensitive (#22)


def test_unsafe_member_reason_table():
    assert unsafe_member_reason("../x") is not None
    assert unsafe_member_reason("a/../../x") is not None
    assert unsafe_member_reason("/abs/path.jpg") is not None
    assert unsafe_member_reason("C:/win.jpg") is not None
    assert unsafe_member_reason("ok/dir/a..b.jpg") is None


def _make_zip(path: Path) -> None:
    with zipfile.ZipFile(path, "w") as z:
        z.writestr("dir/sub/a.jpg", jpeg_bytes(1))
        z.writestr("b.jpg", jpeg_bytes(2))
        z.writestr("../x.jpg", jpeg_bytes(3))
        z.writestr("/abs/path.jpg", jpeg_bytes(4))
        link = zipfile.ZipInfo("link.jpg")
        link.external_attr = 0o120777 << 16
        z.writestr(link, "/etc/passwd")
        z.writestr("corrupt.jpg", jpeg_bytes(5)[:300])
        z.writestr("notes.txt", b"not an image")


def _make_tar(path: Path, mode: str) -> None:
    with tarfile.open(path, mode) as t:
        for name, data in [("dir/sub/a.jpg", jpeg_bytes(1)), ("../x.jpg", jpeg_bytes(3)),
                           ("/abs/path.jpg", jpeg_bytes(4)), ("corrupt.jpg", jpeg_bytes(5)[:300]),
                           ("notes.txt", b"not an image")]:
            info = tarfile.TarInfo(name)
            info.size = len(data)
            t.addfile(info, io.BytesIO(data))
        for name, kind in [("sym.jpg", tarfile.SYMTYPE), ("hard.jpg", tarfile.LNKTYPE)]:
            info = tarfile.TarInfo(name)
            info.type = kind
            info.linkname = "/etc/passwd"
            t.addfile(info)


def _check_archive_records(recs: dict[str, dict], base: str) -> None:
    ok = recs[f"{base}!dir/sub/a.jpg"]
    assert ok["protected"] is False and ok["error"] is None and ok["size_bytes"] > 0
    assert recs[f"{base}!../x.jpg"]["code"] == "unsafe_member_name"
    assert recs[f"{base}!/abs/path.jpg"]["code"] == "unsafe_member_name"
    assert recs[f"{base}!corrupt.jpg"]["code"] == "undecodable_image"
    assert f"{base}!notes.txt" not in recs  # not an image by name or bytes: ignored (#22)
    for r in recs.values():
        assert r["error"] is None or r["protected"] is None
        assert isinstance(r["key"], str) and r["key"]


def test_zip_and_tar_members_in_memory(tmp_path, run_cli):
    arch = tmp_path / "in"
    arch.mkdir()
    _make_zip(arch / "a.zip")
    _make_tar(arch / "b.tar", "w")
    _make_tar(arch / "c.tgz", "w:gz")
    before = set(tmp_path.rglob("*"))
    out = tmp_path / "out.jsonl"
    res = run_cli("scan", arch, "--output", out, "--jobs", "2", "--quiet")
    assert res.exit_code == 3, res.output  # hostile members are errors: not "clean"
    recs = {r["path"]: r for r in read_jsonl(out)}
    assert len(recs) == 6 + 6 + 6
    for name in ("a.zip", "b.tar", "c.tgz"):
        _check_archive_records(recs, f"{arch / name}")
    assert recs[f"{arch / 'a.zip'}!link.jpg"]["code"] == "link_member"
    assert recs[f"{arch / 'b.tar'}!sym.jpg"]["code"] == "link_member"
    assert recs[f"{arch / 'c.tgz'}!hard.jpg"]["code"] == "link_member"
    # nothing extracted or written anywhere but the output file
    assert set(tmp_path.rglob("*")) - before == {out}
    assert not (tmp_path / "x.jpg").exists() and not Path("/abs/path.jpg").exists()


def test_broken_archive_is_one_record(tmp_path, run_cli):
    (tmp_path / "broken.zip").write_bytes(b"PK\x03\x04 not really a zip")
    (tmp_path / "broken.tar.gz").write_bytes(b"\x1f\x8b\x08 truncated")
    write_images(tmp_path, ["ok.jpg"])
    out = tmp_path / "o.jsonl"
    res = run_cli("scan", tmp_path, "-o", out, "--jobs", "1", "--quiet")
    assert res.exit_code == 3
    recs = {Path(r["path"]).name: r for r in read_jsonl(out)}
    assert recs["broken.zip"]["code"] == "unreadable_archive"
    assert recs["broken.tar.gz"]["code"] == "truncated_archive"
    assert recs["ok.jpg"]["protected"] is False
