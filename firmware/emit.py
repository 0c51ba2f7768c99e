"""Write compiled LED sequences as a C header, JSON or CRC-checked binary, and read them back.

Binary format ``LSHD`` version 1 (all integers little-endian, no padding)::

    offset  size        field
    0       4           magic b"LSHD"
    4       2   u16     version (= 1)
    6       4   u32     clock_hz, timer tick rate in Hz (>= 1)
    10      2   u16     max_level, full-on level (>= 1); levels run 0..max_level
    12      1   u8      n_channels (>= 1)
    13      ...         n_channels names, each: u8 length (1..255) + that many UTF-8 bytes
    ...     4   u32     n_records (>= 1)
    ...     ...         n_records records, each: u32 duration_ticks (>= 1)
                        + n_channels x u16 level (<= max_level)
    end-4   4   u32     CRC-32 (zlib.crc32, IEEE 802.3) of every byte before it

The records loop: after the last one the player starts again with the first. Readers reject a
bad magic, an unknown version, truncation, trailing bytes, a CRC mismatch and out-of-range
values with a `FirmwareError` that names the problem.
"""

from __future__ import annotations

import json
import math
import re
import struct
import zlib

import numpy as np

from firmware.sequence import Sequence, SequenceTable, achieved_report
from lishield_guard.errors import FirmwareError

__all__ = [
    "BINARY_MAGIC",
    "BINARY_VERSION",
    "JSON_FORMAT",
    "read_binary",
    "read_json",
    "to_binary",
    "to_c_header",
    "to_json",
]

BINARY_MAGIC = b"LSHD"
BINARY_VERSION = 1
JSON_FORMAT = "lishield-sequence"
JSON_VERSION = 1
_HEAD = struct.Struct("<4sHIHB")  # magic, version, clock_hz, max_level, n_channels
_U32 = struct.Struct("<I")


def _as_table(seq: Sequence | SequenceTable) -> SequenceTable:
    return seq.table() if isinstance(seq, Sequence) else seq


# ---------------------------------------------------------------------- binary
def to_binary(seq: Sequence | SequenceTable) -> bytes:
    """Encode a sequence in the ``LSHD`` binary format (see module docstring).

    Parameters
    ----------
    seq : Sequence or SequenceTable
        The steps to write.

    Returns
    -------
    data : bytes
        Header, records and trailing CRC-32; ``read_binary(data)`` gives the same steps.

    Raises
    ------
    FirmwareError
        If a channel name is empty or longer than 255 UTF-8 bytes, or there are more than 255
        channels.
    """
    t = _as_table(seq)
    if len(t.channels) > 255:
        raise FirmwareError(f"at most 255 channels fit the binary format, got {len(t.channels)}")
    out = bytearray(_HEAD.pack(BINARY_MAGIC, BINARY_VERSION, t.clock_hz, t.max_level,
                               len(t.channels)))
    for name in t.channels:
        raw = name.encode("utf-8")
        if not 1 <= len(raw) <= 255:
            raise FirmwareError(f"channel name {name!r} must be 1..255 UTF-8 bytes")
        out += bytes([len(raw)]) + raw
    out += _U32.pack(t.n_steps)
    rec = np.dtype([("d", "<u4"), ("l", "<u2", (len(t.channels),))])
    body = np.empty(t.n_steps, dtype=rec)
    body["d"] = t.durations_ticks
    body["l"] = t.levels
    out += body.tobytes()
    out += _U32.pack(zlib.crc32(out))
    return bytes(out)


def read_binary(data: bytes) -> SequenceTable:
    """Decode an ``LSHD`` binary sequence.

    Parameters
    ----------
    data : bytes
        The whole file.

    Returns
    -------
    SequenceTable
        Clock, channel names, max level, durations and levels exactly as written.

    Raises
    ------
    FirmwareError
        If the magic or version is wrong, the data is truncated or has trailing bytes, the
        CRC-32 does not match, or a value is out of range.
    """
    data = bytes(data)
    if len(data) < 4 or data[:4] != BINARY_MAGIC:
        raise FirmwareError(f"bad magic {data[:4]!r}: not an LSHD sequence file "
                            f"(expected {BINARY_MAGIC!r})")
    if len(data) < _HEAD.size:
        raise FirmwareError(f"truncated header: {len(data)} bytes, need at least {_HEAD.size}")
    _, version, clock_hz, max_level, n_ch = _HEAD.unpack_from(data, 0)
    if version != BINARY_VERSION:
        raise FirmwareError(f"unknown LSHD version {version}; this reader knows version "
                            f"{BINARY_VERSION}")
    pos = _HEAD.size
    names = []
    for i in range(n_ch):
        if pos >= len(data):
            raise FirmwareError(f"truncated: channel name {i} is missing")
        n = data[pos]
        pos += 1
        if pos + n > len(data):
            raise FirmwareError(f"truncated: channel name {i} needs {n} bytes")
        try:
            names.append(data[pos:pos + n].decode("utf-8"))
        except UnicodeDecodeError as exc:
            raise FirmwareError(f"channel name {i} is not valid UTF-8") from exc
        pos += n
    if pos + 4 > len(data):
        raise FirmwareError("truncated: record count is missing")
    (n_rec,) = _U32.unpack_from(data, pos)
    pos += 4
    rec_size = 4 + 2 * n_ch
    need = pos + n_rec * rec_size + 4
    if len(data) < need:
        raise FirmwareError(f"truncated: {n_rec} records need {need} bytes in all, got "
                            f"{len(data)}")
    if len(data) > need:
        raise FirmwareError(f"{len(data) - need} trailing bytes after the CRC-32")
    (crc,) = _U32.unpack_from(data, need - 4)
    actual = zlib.crc32(data[:need - 4])
    if crc != actual:
        raise FirmwareError(f"CRC-32 mismatch: file says {crc:#010x}, data gives {actual:#010x}")
    if n_ch < 1 or n_rec < 1:
        raise FirmwareError(f"need >= 1 channel and >= 1 record, got {n_ch} and {n_rec}")
    rec = np.dtype([("d", "<u4"), ("l", "<u2", (n_ch,))])
    body = np.frombuffer(data, dtype=rec, count=n_rec, offset=pos)
    return SequenceTable(clock_hz=clock_hz, channels=tuple(names),
                         durations_ticks=body["d"].astype(np.uint32),
                         levels=body["l"].astype(np.uint16).reshape(n_rec, n_ch),
                         max_level=max_level)


# ---------------------------------------------------------------------- JSON
def _finite(x):
    """JSON has no inf/NaN: map them to None."""
    if isinstance(x, float) and not math.isfinite(x):
        return None
    if isinstance(x, dict):
        return {k: _finite(v) for k, v in x.items()}
    if isinstance(x, list):
        return [_finite(v) for v in x]
    return x


def to_json(seq: Sequence | SequenceTable, *, indent: int | None = None) -> str:
    """Encode a sequence as JSON text.

    Parameters
    ----------
    seq : Sequence or SequenceTable
        The steps to write. A `Sequence` also writes its spec and achieved-frequency report.
    indent : int, optional
        Passed to `json.dumps`. Default compact.

    Returns
    -------
    text : str
        An object with ``format``, ``version``, ``clock_hz``, ``channels``, ``max_level``,
        ``period_ticks``, ``durations_ticks`` (list of int) and ``levels`` (list of lists,
        one per step), plus ``spec`` and ``report`` for a `Sequence`.
    """
    t = _as_table(seq)
    obj: dict = {"format": JSON_FORMAT, "version": JSON_VERSION, "clock_hz": t.clock_hz,
                 "channels": list(t.channels), "max_level": t.max_level,
                 "period_ticks": t.period_ticks,
                 "durations_ticks": t.durations_ticks.tolist(), "levels": t.levels.tolist()}
    if isinstance(seq, Sequence):
        obj["spec"] = seq.spec.to_dict()
        obj["n_patterns"] = seq.n_patterns
        obj["report"] = _finite(achieved_report(seq))
    return json.dumps(obj, indent=indent)


def read_json(text: str) -> SequenceTable:
    """Decode the JSON written by `to_json`.

    Raises
    ------
    FirmwareError
        If the text is not JSON, not this format or version, or holds bad values.
    """
    try:
        obj = json.loads(text)
    except json.JSONDecodeError as exc:
        raise FirmwareError(f"not valid JSON: {exc}") from exc
    if not isinstance(obj, dict) or obj.get("format") != JSON_FORMAT:
        raise FirmwareError(f"not a {JSON_FORMAT!r} JSON document")
    if obj.get("version") != JSON_VERSION:
        raise FirmwareError(f"unknown {JSON_FORMAT} version {obj.get('version')!r}")
    try:
        t = SequenceTable(clock_hz=obj["clock_hz"], channels=tuple(obj["channels"]),
                          durations_ticks=np.asarray(obj["durations_ticks"], dtype=np.int64),
                          levels=np.asarray(obj["levels"], dtype=np.int64).reshape(
                              -1, len(obj["channels"])),
                          max_level=obj["max_level"])
    except (KeyError, TypeError, ValueError) as exc:
        if isinstance(exc, FirmwareError):
            raise
        raise FirmwareError(f"bad {JSON_FORMAT} document: {exc!r}") from exc
    if "period_ticks" in obj and obj["period_ticks"] != t.period_ticks:
        raise FirmwareError(f"period_ticks={obj['period_ticks']} disagrees with the durations "
                            f"(sum {t.period_ticks})")
    return t


# ---------------------------------------------------------------------- C header
def _c_comment(text: str) -> str:
    return text.replace("*/", "* /")


def to_c_header(seq: Sequence | SequenceTable, *, symbol: str = "lsp_seq",
                values_per_line: int = 8) -> str:
    """Encode a sequence as a self-contained C99 header of const arrays.

    Parameters
    ----------
    seq : Sequence or SequenceTable
        The steps to write. A `Sequence` also writes its spec and achieved frequencies in the
        leading comment block.
    symbol : str, optional
        C identifier prefix: arrays ``<symbol>_durations_ticks`` and ``<symbol>_levels``
        (row-major, ``n_steps * n_channels``), macros ``<SYMBOL>_N_STEPS``, ``_N_CHANNELS``,
        ``_CLOCK_HZ``, ``_MAX_LEVEL``, ``_PERIOD_TICKS``. Default ``"lsp_seq"``.
    values_per_line : int, optional
        Array values per source line, >= 1. Default 8.

    Returns
    -------
    text : str
        The header, with an include guard; arrays are ``static const`` so it can be included
        by one translation unit that passes them to `lsp_init`.

    Raises
    ------
    FirmwareError
        If ``symbol`` is not a valid C identifier.
    """
    if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", symbol):
        raise FirmwareError(f"symbol must be a C identifier, got {symbol!r}")
    t = _as_table(seq)
    up = symbol.upper()
    guard = f"{up}_H"
    meta = [f"LiShield LED sequence, generated by lishield-guard firmware (format {JSON_FORMAT} "
            f"v{JSON_VERSION}). Do not edit.",
            "",
            f"clock:        {t.clock_hz} Hz timer ticks",
            f"channels:     {', '.join(t.channels)} (levels 0..{t.max_level})",
            f"steps:        {t.n_steps}",
            f"period:       {t.period_ticks} ticks = {t.period_s * 1e3:.6g} ms (loops forever)"]
    if isinstance(seq, Sequence):
        rep = achieved_report(seq)
        s = seq.spec
        order_kind = "explicit" if isinstance(s.order, tuple) else s.order
        meta += ["",
                 f"spec:         {s.name}",
                 "tones:        " + "; ".join(f"{c}: {', '.join(f'{f:g}' for f in fs)} Hz"
                                               for c, fs in s.channels),
                 f"f_B:          {s.f_b_hz:g} Hz, duty {s.duty:g}, slot order "
                 f"{','.join(map(str, s.slot_order()))} ({order_kind}), "
                 f"phase {s.phase}, intensity levels {s.intensity_levels}",
                 f"patterns:     {seq.n_patterns} x M/f_B = {rep['pattern_period_s'] * 1e3:.6g} ms",
                 f"slot rate:    {rep['slot_rate_hz']:.6f} Hz achieved",
                 "achieved:     channel  spec Hz  achieved Hz (min..max)  rel. error"]
        for tone in rep["tones"]:
            meta.append(f"              {tone['channel']:<7}  {tone['spec_hz']:7g}  "
                        f"{tone['achieved_hz']:.4f} ({tone['min_hz']:.4f}..{tone['max_hz']:.4f})"
                        f"  {tone['rel_error']:.2e}")
        meta.append(f"worst ratio relative error: {rep['worst_ratio_error']:.3e}")
    lines = ["/*"] + [_c_comment(f" * {m}".rstrip()) for m in meta] + [" */",
             f"#ifndef {guard}", f"#define {guard}", "", "#include <stdint.h>", "",
             f"#define {up}_N_STEPS {t.n_steps}u",
             f"#define {up}_N_CHANNELS {len(t.channels)}u",
             f"#define {up}_CLOCK_HZ {t.clock_hz}ul",
             f"#define {up}_MAX_LEVEL {t.max_level}u",
             f"#define {up}_PERIOD_TICKS {t.period_ticks}ull", "",
             f"/* Channel order: {', '.join(t.channels)} */"]

    def array(ctype: str, name: str, values: list[int], suffix: str) -> list[str]:
        out = [f"static const {ctype} {symbol}_{name}[{len(values)}] = {{"]
        n = max(1, int(values_per_line))
        for i in range(0, len(values), n):
            out.append("    " + ", ".join(f"{v}{suffix}" for v in values[i:i + n]) + ",")
        return out + ["};", ""]

    lines += array("uint32_t", "durations_ticks", t.durations_ticks.tolist(), "u")
    lines += [f"/* Row-major: {symbol}_levels[step * {up}_N_CHANNELS + channel] */"]
    lines += array("uint16_t", "levels", t.levels.reshape(-1).tolist(), "u")
    lines += [f"#endif /* {guard} */", ""]
    return "\n".join(lines)
