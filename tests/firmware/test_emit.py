"""Emitters: exact binary and JSON round trips, corrupted files, C header content."""

from __future__ import annotations

import dataclasses
import json
import struct
import zlib

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from firmware.emit import read_binary, read_json, to_binary, to_c_header, to_json
from firmware.sequence import SequenceTable, compile_spec
from lishield_guard.errors import FirmwareError
from lishield_guard.spec import PRESETS

RANDOMIZED = dataclasses.replace(PRESETS["table2-rgb"], name="rgb-k4", intensity_levels=4)
SEQS = {name: compile_spec(spec) for name, spec in PRESETS.items()}
SEQS["rgb-k4"] = compile_spec(RANDOMIZED, seed=b"emit-test-secret")


def _recrc(body: bytes) -> bytes:
    return body + struct.pack("<I", zlib.crc32(body))


@pytest.mark.parametrize("name", list(SEQS))
def test_binary_and_json_round_trip_exactly(name):
    seq = SEQS[name]
    data = to_binary(seq)
    back = read_binary(data)
    assert isinstance(back, SequenceTable)
    assert back.same_steps(seq)
    assert back.period_ticks == seq.period_ticks and back.edges(2) == seq.edges(2)
    assert to_binary(back) == data
    jback = read_json(to_json(seq))
    assert jback.same_steps(seq)
    n_ch = len(seq.channels)
    assert len(data) == (4 + 2 + 4 + 2 + 1 + sum(1 + len(c) for c in seq.channels) + 4
                         + seq.n_steps * (4 + 2 * n_ch) + 4)


def test_binary_layout_is_as_documented():
    seq = SEQS["table1-seq1"]
    data = to_binary(seq)
    assert data[:4] == b"LSHD"
    assert struct.unpack_from("<HIHB", data, 4) == (1, 1_000_000, 1, 1)
    assert data[13:15] == b"\x01W"
    assert struct.unpack_from("<I", data, 15) == (8,)
    assert struct.unpack_from("<IH", data, 19) == (1250, 1)
    assert struct.unpack_from("<IH", data, 25) == (1250, 0)
    assert struct.unpack("<I", data[-4:])[0] == zlib.crc32(data[:-4])


@pytest.mark.parametrize(("mutate", "match"), [
    (lambda d: b"LSHX" + d[4:], "bad magic"),
    (lambda d: b"", "bad magic"),
    (lambda d: _recrc(d[:4] + struct.pack("<H", 2) + d[6:-4]), "unknown LSHD version 2"),
    (lambda d: d + b"\x00", "trailing bytes"),
    (lambda d: d[:-1], "truncated"),
    (lambda d: d[:12], "truncated"),
    (lambda d: d[:20], "truncated"),
    (lambda d: d[:-5] + bytes([d[-5] ^ 0x01]) + d[-4:], "CRC-32 mismatch"),
    (lambda d: d[:-4] + bytes(4), "CRC-32 mismatch"),
    # valid CRC but a zero duration / a level above max_level
    (lambda d: _recrc(d[:19] + struct.pack("<I", 0) + d[23:-4]), "duration"),
    (lambda d: _recrc(d[:23] + struct.pack("<H", 9) + d[25:-4]), "levels must be in"),
    (lambda d: _recrc(d[:10] + struct.pack("<H", 0) + d[12:-4]), "max_level"),
])
def test_corrupted_binary_is_rejected(mutate, match):
    data = to_binary(SEQS["table1-seq1"])
    with pytest.raises(FirmwareError, match=match):
        read_binary(mutate(data))


def test_every_truncation_is_rejected():
    data = to_binary(SEQS["table2-rgb"])
    for n in range(len(data)):
        with pytest.raises(FirmwareError):
            read_binary(data[:n])


@settings(max_examples=200, deadline=None)
@given(st.binary(max_size=200), st.booleans())
def test_random_bytes_raise_only_firmware_error(blob, with_header):
    data = (b"LSHD\x01\x00" + blob) if with_header else blob
    try:
        read_binary(data)
    except FirmwareError:
        pass


def test_json_content_and_errors():
    seq = SEQS["table1-seq1"]
    obj = json.loads(to_json(seq))
    assert obj["format"] == "lishield-sequence" and obj["version"] == 1
    assert obj["durations_ticks"][:3] == [1250, 1250, 833]
    assert obj["spec"]["name"] == "table1-seq1"
    assert obj["report"]["worst_ratio_error"] < 1e-3
    for bad, match in [("{", "not valid JSON"), ("[]", "not a"),
                       (json.dumps({**obj, "version": 9}), "unknown"),
                       (json.dumps({**obj, "period_ticks": 1}), "period_ticks"),
                       (json.dumps({k: v for k, v in obj.items() if k != "levels"}), "bad"),
                       (json.dumps({**obj, "durations_ticks": [0] * 8}), "duration")]:
        with pytest.raises(FirmwareError, match=match):
            read_json(bad)


def test_c_header_content():
    seq = SEQS["table2-rgb"]
    text = to_c_header(seq, symbol="venue_seq")
    assert "#ifndef VENUE_SEQ_H" in text and "#define VENUE_SEQ_N_STEPS 42u" in text
    assert "#define VENUE_SEQ_N_CHANNELS 3u" in text
    assert "#define VENUE_SEQ_PERIOD_TICKS 7500ull" in text
    assert "static const uint32_t venue_seq_durations_ticks[42]" in text
    assert "static const uint16_t venue_seq_levels[126]" in text
    assert "spec:         table2-rgb" in text and "worst ratio relative error" in text
    body = text.split("venue_seq_durations_ticks[42] = {")[1].split("};")[0]
    values = [int(v.strip().rstrip("u")) for v in body.replace("\n", "").split(",") if v.strip()]
    assert values == seq.durations_ticks.tolist()
    with pytest.raises(FirmwareError, match="C identifier"):
        to_c_header(seq, symbol="2bad")


def test_table_validation():
    with pytest.raises(FirmwareError, match="shape"):
        SequenceTable(1000, ("W",), np.ones(3), np.zeros((3, 2)), 1)
    with pytest.raises(FirmwareError, match="non-empty"):
        SequenceTable(1000, ("W",), np.ones(0), np.zeros((0, 1)), 1)
    t = SequenceTable(1000, ("W",), np.ones(3), np.zeros((3, 1)), 1)
    with pytest.raises(ValueError):
        t.durations_ticks[0] = 5  # read-only
