"""Issue 42: one registry of profiles, one of media kinds, one way to say undetermined.

A new profile or media kind is one entry and its own module: the tests add a toy one of each at
run time and reach it through the public entry points, with nothing else changed.
"""

from __future__ import annotations

import ast
import sys
import types
from pathlib import Path

import numpy as np
import pytest

import lishield_guard
from lishield_guard import profiles
from lishield_guard.batch import types as kinds
from lishield_guard.config import DetectorConfig, default_config
from lishield_guard.errors import ConfigError
from lishield_guard.verdict import Evidence, Verdict, undetermined

PACKAGE = Path(lishield_guard.__file__).parent
SERVICE = PACKAGE.parent / "service"


def _sources():
    for root in (PACKAGE, SERVICE):
        for path in sorted(root.rglob("*.py")):
            yield path, ast.parse(path.read_text(encoding="utf-8"))


def test_every_profile_module_has_the_hooks_and_its_registry_name():
    for name in profiles.NAMES:
        module = profiles.get(name)
        assert module.NAME == name
        for hook in ("decode", "measure", "decide", "required"):
            assert callable(getattr(module, hook)), (name, hook)
    with pytest.raises(ConfigError, match="profile must be one of"):
        profiles.get("bogus")
    with pytest.raises(ConfigError, match="profile must be one of"):
        DetectorConfig(profile="bogus")


def test_no_profile_name_is_compared_as_a_string_outside_the_registry():
    """The names live in `lishield_guard.profiles` only: no comparison (``==``, ``!=``,
    ``in``) of a string literal that names a profile anywhere else in the package or the
    service (there were about 20 in 6 files)."""
    names = set(profiles.NAMES)
    bad = []
    for path, tree in _sources():
        if path == PACKAGE / "profiles" / "__init__.py":
            continue
        for node in ast.walk(tree):
            if isinstance(node, ast.Compare):
                consts = [c for c in ast.walk(node) if isinstance(c, ast.Constant)
                          and isinstance(c.value, str) and c.value in names]
                bad += [f"{path.name}:{node.lineno}" for _ in consts[:1]]
    assert not bad


def test_one_constructor_builds_every_undetermined_verdict():
    """Only `verdict.undetermined` passes ``undetermined=`` to `Verdict` (there were seven
    hand-built ones, with ``required`` 0, 1 or ``min_tones``)."""
    calls = [f"{path.name}:{node.lineno}" for path, tree in _sources()
             for node in ast.walk(tree)
             if isinstance(node, ast.Call) and getattr(node.func, "id", None) == "Verdict"
             and any(k.arg == "undetermined" for k in node.keywords)]
    assert [c.split(":")[0] for c in calls] == ["verdict.py"], calls
    v = undetermined("too small", looked_at="40 x 40 pixels, grey", profile=profiles.DEFAULT,
                     required=1)
    assert v.status == "undetermined" and v.protected is None and v.matches == 0
    assert v.to_dict()["evidence"] == {"reason": "too small", "looked_at": "40 x 40 pixels, grey"}


@pytest.mark.parametrize("name", profiles.NAMES)
def test_every_profile_says_undetermined_the_same_way(name):
    """A blank frame under each profile: the one constructor's evidence (reason and what was
    looked at) and ``required`` from the profile."""
    cfg = default_config()
    cfg = type(cfg)(detector=cfg.detector.replace(profile=name), limits=cfg.limits,
                    policies=cfg.policies)
    flat = np.full((40, 40), 128, np.uint8)
    v = lishield_guard.detect(flat, cfg)
    if name == profiles.PAPER:  # Algorithm 1 reads 10-row blocks of this frame: not undetermined
        flat = np.full((6, 40), 128, np.uint8)
        v = lishield_guard.detect(flat, cfg)
    assert v.status == "undetermined", v
    ev = v.to_dict()["evidence"]
    assert set(ev) == {"reason", "looked_at"} and ev["reason"] == v.undetermined
    assert v.required == profiles.get(name).required(cfg)


class _ToyEvidence(Evidence):
    reason = "toy"

    def to_dict(self) -> dict:
        return {"reason": self.reason, "stage": "toy"}


def _toy_profile() -> types.ModuleType:
    """A profile module: four hooks and its name, nothing else."""
    mod = types.ModuleType("toy_profile_for_tests")
    mod.NAME = "toy"
    mod.required = lambda config: 1
    mod.decode = lambda source, config: lishield_guard.decode(source, limits=config.limits)
    mod.measure = lambda decoded, config, timer: float(decoded.luma.mean())
    mod.decide = lambda record, config, timer: Verdict(
        record > 100, "no-distribution" if record > 100 else None, int(record > 100), 1,
        evidence=_ToyEvidence(), profile=mod.NAME, timings_ms=timer.ms)
    return mod


def test_a_new_profile_is_one_registry_entry_and_its_module(monkeypatch):
    """Registered under a name, the toy profile is what `detect` runs for a config that names
    it; nothing else of the package changes."""
    monkeypatch.setitem(sys.modules, "toy_profile_for_tests", _toy_profile())
    monkeypatch.setitem(profiles.REGISTRY, "toy", "toy_profile_for_tests")
    cfg = default_config()
    cfg = type(cfg)(detector=cfg.detector.replace(profile="toy"), limits=cfg.limits,
                    policies=cfg.policies)
    bright = np.full((100, 100), 200, np.uint8)
    v = lishield_guard.detect(bright, cfg)
    assert (v.status, v.profile, v.to_dict()["evidence"]["stage"]) == ("protected", "toy", "toy")


def test_a_new_media_kind_is_one_registry_entry_and_its_module(monkeypatch, tmp_path):
    """A toy kind (its own signature, detect function and caps) is sniffed, capped and
    screened by `detect_media` and the service's settings, with nothing else changed."""
    from lishield_guard.video import detect_media

    mod = types.ModuleType("toy_kind_for_tests")
    mod.detect = lambda source, config=None: Verdict(False, None, 0, 1, evidence={
        "reason": "toy kind", "stage": "toy"})
    monkeypatch.setitem(sys.modules, "toy_kind_for_tests", mod)
    toy = kinds.MediaKind("toy", (".toy",), ("application/x-toy",),
                          lambda head: head.startswith(b"TOY1"), "toy_kind_for_tests:detect",
                          "limits.max_bytes", "max_upload_bytes", "detect_timeout_s")
    monkeypatch.setattr(kinds, "KINDS", (*kinds.KINDS, toy))
    data = b"TOY1 not an image"
    assert kinds.kind_of_bytes(data) is toy and kinds.kind_of_name("a.TOY") is toy
    assert detect_media(data).evidence.reason == "toy kind"
    path = tmp_path / "x.toy"
    path.write_bytes(data)
    assert detect_media(str(path)).evidence.reason == "toy kind"
    assert toy.cap_bytes(default_config()) == default_config().limits.max_bytes
    pytest.importorskip("pydantic_settings")
    from service.settings import ServiceSettings

    s = ServiceSettings(_env_file=None)
    assert s.upload_cap("toy") == ("max_upload_bytes", s.max_upload_bytes)
    assert s.time_budget("toy") == ("detect_timeout_s", s.detect_timeout_s)


def test_one_brand_table_tells_images_from_videos():
    """Every ISO-BMFF brand is either a still image's or a video's, never both or neither
    (``avis``, an AVIF image sequence, was a still for the video test and nothing for the
    image test)."""
    for brand in (*kinds.IMAGE_BRANDS, b"isom", b"mp42", b"qt  "):
        head = b"\0\0\0\x20ftyp" + brand
        assert kinds.is_image_bytes(head) != kinds.is_video_bytes(head), brand
    assert kinds.kind_of_bytes(b"\0\0\0\x20ftypavis") is kinds.IMAGE


def test_the_media_kinds_carry_their_caps_and_budgets():
    cfg = default_config()
    assert kinds.IMAGE.cap_bytes(cfg) == cfg.limits.max_bytes
    assert kinds.VIDEO.cap_bytes(cfg) == cfg.video.limits.max_bytes
    assert {k.name for k in kinds.KINDS} == {"image", "video"}
    assert kinds.kind_of_source(np.zeros((4, 4), np.uint8)) is kinds.IMAGE
    assert kinds.kind_of_source("/no/such/clip.MOV") is kinds.VIDEO
