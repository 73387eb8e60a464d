#!/usr/bin/env python3
"""Read lfr sample files (docs/sample-format.md, format version 1) with numpy alone.

    import read_samples
    header, records = read_samples.load("samples.lfrs")      # structured np.memmap, no copy
    cols = read_samples.fields("samples.lfrs")               # name -> (sample_count, components)
    x = cols["x"][:, 0]

Command line:

    python3 docs/tools/read_samples.py FILE [--json OUT] [--no-verify]

prints a summary of the header and, with --json, writes per-field first values and nan-aware
means (non-finite numbers as the strings "nan", "inf", "-inf") for cross-checking.

Requires Python 3.9+ and numpy; nothing else.
"""

import argparse
import json
import os
import struct
import sys
import zlib
from typing import Any, Dict, List, Tuple

try:
    import numpy as np
except ImportError:  # pragma: no cover - exercised by hand
    sys.stderr.write("read_samples.py needs numpy: pip install numpy\n")
    sys.exit(2)

MAGIC = b"LFRSAMP\0"
TRAILER_MAGIC = b"LFRTAIL\0"
FORMAT_VERSION = 1
PREAMBLE_LEN = 16
TRAILER_LEN = 32
DATA_ALIGN = 64
MAX_HEADER_LEN = 16 << 20

NUMPY_TYPES = {"f32": "<f4", "f16": "<f2", "u32": "<u4", "u16": "<u2", "u8": "u1"}
TYPE_SIZES = {"f32": 4, "f16": 2, "u32": 4, "u16": 2, "u8": 1}

# Bytes hashed per read when verifying: whole chunks, about this much at a time.
_READ_BYTES = 1 << 24


class SampleFileError(ValueError):
    """A file that is not a valid lfr sample file; the message starts with the path."""

    def __init__(self, path: str, message: str) -> None:
        super().__init__("%s: %s" % (path, message))
        self.path = path


class _Layout:
    def __init__(self, header: Dict[str, Any], header_bytes: bytes, data_offset: int, size: int) -> None:
        self.header = header
        self.header_bytes = header_bytes
        self.data_offset = data_offset
        self.size = size
        self.sample_count = int(header["sample_count"])
        self.record_size = int(header["record_size"])
        self.chunk_samples = int(header.get("chunk_samples", 65536))
        self.chunks = -(-self.sample_count // self.chunk_samples)
        self.data_len = self.sample_count * self.record_size
        self.table_offset = data_offset + self.data_len


def _check_header(path: str, h: Any) -> None:
    def bad(key: str, message: str) -> SampleFileError:
        return SampleFileError(path, "invalid `%s`: %s" % (key, message))

    if not isinstance(h, dict):
        raise bad("header", "not a JSON object")
    if h.get("format") != "lfr-samples":
        raise bad("format", "is %r, expected 'lfr-samples'" % (h.get("format"),))
    if h.get("version") != FORMAT_VERSION:
        raise bad("version", "the header says %r, the preamble says %d" % (h.get("version"), FORMAT_VERSION))
    for key in ("kind", "width", "height", "spp", "sample_count", "order", "record_size", "fields"):
        if key not in h:
            raise bad(key, "missing")
    for key, limit in (("width", 65536), ("height", 65536), ("spp", 1 << 20)):
        v = h[key]
        if not isinstance(v, int) or not 1 <= v <= limit:
            raise bad(key, "%r is outside 1..=%d" % (v, limit))
    if h["sample_count"] != h["width"] * h["height"] * h["spp"]:
        raise bad("sample_count", "%r is not width * height * spp" % (h["sample_count"],))
    if h["order"] != "pixel-major":
        raise bad("order", "%r is not 'pixel-major'" % (h["order"],))
    chunk = h.get("chunk_samples", 65536)
    if not isinstance(chunk, int) or chunk < 1:
        raise bad("chunk_samples", "%r is not a positive integer" % (chunk,))
    rs = h["record_size"]
    if not isinstance(rs, int) or not 0 < rs <= 65536:
        raise bad("record_size", "%r is outside 1..=65536" % (rs,))
    fields = h["fields"]
    if not isinstance(fields, list) or not 1 <= len(fields) <= 64:
        raise bad("fields", "must be a list of 1 to 64 fields")
    names = set()
    spans = []
    for i, f in enumerate(fields):
        key = "fields[%d]" % i
        if not isinstance(f, dict) or not {"name", "type", "components", "offset"} <= set(f):
            raise bad(key, "needs name, type, components and offset")
        if f["name"] in names:
            raise bad(key + ".name", "duplicate field name %r" % (f["name"],))
        names.add(f["name"])
        if f["type"] not in NUMPY_TYPES:
            raise bad(key + ".type", "unknown type %r" % (f["type"],))
        size = TYPE_SIZES[f["type"]]
        if not isinstance(f["components"], int) or not 1 <= f["components"] <= 4:
            raise bad(key + ".components", "%r is outside 1..=4" % (f["components"],))
        off = f["offset"]
        if not isinstance(off, int) or off < 0 or off % size:
            raise bad(key + ".offset", "%r is not a multiple of %d" % (off, size))
        end = off + size * f["components"]
        if end > rs:
            raise bad(key + ".offset", "the field ends at %d, past the record size %d" % (end, rs))
        spans.append((off, end, i))
    spans.sort()
    for a, b in zip(spans, spans[1:]):
        if b[0] < a[1]:
            raise bad("fields[%d].offset" % b[2], "overlaps another field")
    need = -(-max(s[1] for s in spans) // 4) * 4
    if rs != need:
        raise bad("record_size", "%d does not match the fields, which need %d" % (rs, need))


def _reject_constant(name: str) -> None:
    raise ValueError("%s is not valid JSON" % name)


def _read_layout(path: str) -> _Layout:
    path = os.fspath(path)
    size = os.path.getsize(path)
    with open(path, "rb") as f:
        pre = f.read(PREAMBLE_LEN)
        if pre[: len(MAGIC)] != MAGIC[: len(pre[: len(MAGIC)])]:
            raise SampleFileError(path, "not an lfr sample file (bad magic)")
        if len(pre) < PREAMBLE_LEN:
            raise SampleFileError(path, "truncated: the preamble needs %d bytes, the file has %d" % (PREAMBLE_LEN, size))
        version, header_len = struct.unpack("<II", pre[8:16])
        if version != FORMAT_VERSION:
            raise SampleFileError(path, "unsupported sample format version %d" % version)
        if header_len > MAX_HEADER_LEN or (PREAMBLE_LEN + header_len) % DATA_ALIGN:
            raise SampleFileError(path, "invalid `header_length`: %d" % header_len)
        header_bytes = f.read(header_len)
        if len(header_bytes) < header_len:
            raise SampleFileError(
                path, "truncated: the header needs %d bytes, the file has %d" % (PREAMBLE_LEN + header_len, size)
            )
    try:
        header = json.loads(header_bytes.decode("utf-8"), parse_constant=_reject_constant)
    except (UnicodeDecodeError, ValueError) as e:
        raise SampleFileError(path, "invalid `header`: %s" % e) from None
    _check_header(path, header)
    layout = _Layout(header, header_bytes, PREAMBLE_LEN + header_len, size)
    expected = layout.table_offset + 4 * layout.chunks + TRAILER_LEN
    if size < expected:
        raise SampleFileError(path, "truncated: the file has %d bytes, its header needs %d" % (size, expected))
    if size > expected:
        raise SampleFileError(path, "invalid `file_size`: %d bytes, the header accounts for %d" % (size, expected))
    return layout


def _verify(path: str, layout: _Layout, data: bool) -> None:
    """Checks the trailer, the header and chunk-table CRCs and, if `data`, every chunk's CRC."""
    with open(path, "rb") as f:
        f.seek(layout.table_offset)
        table = f.read(4 * layout.chunks)
        trailer = f.read(TRAILER_LEN)
        magic, count, header_crc, table_crc, chunks = struct.unpack("<8sQIIQ", trailer)
        if magic != TRAILER_MAGIC:
            raise SampleFileError(path, "corrupted trailer: bad magic")
        if count != layout.sample_count or chunks != layout.chunks:
            raise SampleFileError(path, "corrupted trailer: counts disagree with the header")
        if zlib.crc32(layout.header_bytes) != header_crc:
            raise SampleFileError(path, "corrupted header: CRC-32 mismatch")
        if zlib.crc32(table) != table_crc:
            raise SampleFileError(path, "corrupted trailer: chunk table CRC-32 mismatch")
        if not data:
            return
        crcs = struct.unpack("<%dI" % layout.chunks, table)
        chunk_bytes = layout.chunk_samples * layout.record_size
        per_read = max(1, _READ_BYTES // chunk_bytes)
        f.seek(layout.data_offset)
        c = 0
        while c < layout.chunks:
            block = f.read(min(per_read * chunk_bytes, layout.data_len - c * chunk_bytes))
            for start in range(0, len(block), chunk_bytes):
                if zlib.crc32(block[start : start + chunk_bytes]) != crcs[c]:
                    raise SampleFileError(
                        path, "corrupted data: chunk %d (samples %d..) fails its CRC-32" % (c, c * layout.chunk_samples)
                    )
                c += 1


def dtype(header: Dict[str, Any]) -> "np.dtype":
    """The structured numpy dtype of one record: one named member per field, components as a
    sub-array of shape (components,) (a scalar for one component), at the header's offsets."""
    names, formats, offsets = [], [], []
    for f in header["fields"]:
        names.append(f["name"])
        base = NUMPY_TYPES[f["type"]]
        formats.append(base if f["components"] == 1 else (base, (f["components"],)))
        offsets.append(f["offset"])
    return np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": header["record_size"]})


def load(path: str, verify: bool = True) -> Tuple[Dict[str, Any], "np.memmap"]:
    """Returns (header dict, read-only structured memmap of all records, shape (sample_count,)).

    Magic, version, header and file size are always checked, as are the trailer and the header
    and chunk-table CRCs; `verify` adds the CRC of every data chunk.
    """
    path = os.fspath(path)
    layout = _read_layout(path)
    _verify(path, layout, verify)
    records = np.memmap(path, dtype=dtype(layout.header), mode="r", offset=layout.data_offset, shape=(layout.sample_count,))
    return layout.header, records


def fields(path: str, verify: bool = True, f16_to_f32: bool = False) -> Dict[str, "np.ndarray"]:
    """Returns name -> array of shape (sample_count, components), views into the memmap (no
    copies), except that f16 fields are converted to float32 (a copy) if `f16_to_f32`."""
    header, records = load(path, verify)
    out = {}
    for f in header["fields"]:
        a = records[f["name"]]
        if f["components"] == 1:
            a = a.reshape(len(records), 1)
        if f16_to_f32 and f["type"] == "f16":
            a = a.astype(np.float32)
        out[f["name"]] = a
    return out


def _number(v: float) -> Any:
    """JSON-safe number: non-finite values as strings."""
    v = float(v)
    if np.isnan(v):
        return "nan"
    if np.isinf(v):
        return "inf" if v > 0 else "-inf"
    return v


def _nanmean(a: "np.ndarray") -> List[float]:
    """Per-column mean over non-NaN values, in float64, a block of samples at a time."""
    total = np.zeros(a.shape[1], dtype=np.float64)
    count = np.zeros(a.shape[1], dtype=np.int64)
    step = 1 << 20
    for start in range(0, a.shape[0], step):
        block = np.asarray(a[start : start + step], dtype=np.float64)
        ok = ~np.isnan(block)
        total += np.where(ok, block, 0.0).sum(axis=0)
        count += ok.sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        return [float(x) for x in np.where(count > 0, total / np.maximum(count, 1), np.nan)]


def summary(path: str, header: Dict[str, Any]) -> str:
    lines = [
        "%s: lfr samples v%d, kind %s, %dx%d pixels, %d spp, %d samples of %d bytes, chunks of %d"
        % (
            path,
            header["version"],
            header["kind"],
            header["width"],
            header["height"],
            header["spp"],
            header["sample_count"],
            header["record_size"],
            header.get("chunk_samples", 65536),
        )
    ]
    for key in ("scene", "seed"):
        if key in header:
            lines.append("  %s: %s" % (key, header[key]))
    for key in ("camera", "light", "coordinates", "extra"):
        if key in header:
            lines.append("  %s: present" % key)
    lines.append("  fields:")
    for f in header["fields"]:
        lines.append(
            "    %-16s %-3s x%d  @%-4d %-12s %s"
            % (f["name"], f["type"], f["components"], f["offset"], f.get("unit", ""), f.get("meaning", ""))
        )
    return "\n".join(lines)


def main(argv: List[str]) -> int:
    parser = argparse.ArgumentParser(description="Summarize (and check) an lfr sample file.")
    parser.add_argument("file")
    parser.add_argument("--json", metavar="OUT", help="write per-field first 5 values and nan-aware means")
    parser.add_argument("--no-verify", action="store_true", help="skip the data-chunk CRCs")
    args = parser.parse_args(argv)
    try:
        header, records = load(args.file, verify=not args.no_verify)
    except (SampleFileError, OSError) as e:
        sys.stderr.write("error: %s\n" % e)
        return 1
    print(summary(args.file, header))
    if args.json:
        cols = fields(args.file, verify=False)
        report = {"path": args.file, "header": header, "sample_count": len(records), "fields": {}}
        for f in header["fields"]:
            a = cols[f["name"]]
            report["fields"][f["name"]] = {
                "type": f["type"],
                "components": f["components"],
                "first": [[_number(v) for v in row] for row in np.asarray(a[:5], dtype=np.float64)],
                "mean": [_number(m) for m in _nanmean(a)],
            }
        with open(args.json, "w", encoding="utf-8") as out:
            json.dump(report, out, indent=1, allow_nan=False)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
