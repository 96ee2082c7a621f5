"""Mutation primitives: of bytes at known fields, of raw bytes, and of JSON documents.

Every function takes a :class:`random.Random` and returns the mutated value with a short
description (which goes into the report, so that a case can be understood without replaying
it)."""

from __future__ import annotations

import copy
import json
import random
import struct
from collections.abc import Sequence
from typing import Any

#: Integers a length or count field is set to: the edges of each width and of the limits.
BOUNDARY_INTS = (
    0, 1, 2, 3, 7, 8, 15, 16, 17, 255, 256, 512, 513, 1023, 4095, 4096, 8191, 8192, 16384, 16385,
    32767, 32768, 65535, 65536, (1 << 25), (1 << 25) + 1, (1 << 31) - 1, 1 << 31, (1 << 32) - 1,
    (1 << 63) - 1, 1 << 63, (1 << 64) - 1,
)
#: Floats a number field is set to.
BOUNDARY_FLOATS = (
    0.0, -0.0, -1.0, 1e-45, 5e-324, 1e-300, 1e38, 3.5e38, 1e300, 1.7976931348623157e308,
    -1e300, float("nan"), float("inf"), float("-inf"),
)
_FORMATS = {1: "<B", 2: "<H", 4: "<I", 8: "<Q"}


def set_int(data: bytes, offset: int, width: int, rng: random.Random) -> tuple[bytes, str]:
    """``data`` with the little-endian unsigned field of ``width`` bytes at ``offset`` set to
    a boundary value (or a random one)."""
    top = (1 << (8 * width)) - 1
    choices = [v for v in BOUNDARY_INTS if v <= top]
    old = int.from_bytes(data[offset : offset + width], "little")
    choices += [max(0, old - 1), min(top, old + 1), rng.randrange(top + 1)]
    v = rng.choice(choices)
    out = bytearray(data)
    out[offset : offset + width] = struct.pack(_FORMATS[width], v)
    return bytes(out), f"u{8 * width}@{offset}: {old} -> {v}"


def set_float(data: bytes, offset: int, rng: random.Random) -> tuple[bytes, str]:
    """``data`` with the f64 at ``offset`` set to a boundary value."""
    v = rng.choice(BOUNDARY_FLOATS)
    out = bytearray(data)
    out[offset : offset + 8] = struct.pack("<d", v)
    return bytes(out), f"f64@{offset} -> {v!r}"


def mutate_bytes(data: bytes, rng: random.Random, lo: int = 0, hi: int | None = None) -> tuple[bytes, str]:
    """One generic mutation of ``data[lo:hi]``: truncation, bit flips, a byte or a run set,
    bytes inserted or removed, a run duplicated or two runs swapped."""
    hi = len(data) if hi is None else hi
    if hi <= lo:
        return data[: max(0, lo - 1)], f"truncated to {max(0, lo - 1)} bytes"
    op = rng.choice(("truncate", "flip", "flip", "flips", "byte", "insert", "delete", "dup", "swap"))
    b = bytearray(data)
    at = rng.randrange(lo, hi)
    if op == "truncate":
        cut = rng.randrange(lo, hi)
        return bytes(b[:cut]), f"truncated to {cut} of {len(data)} bytes"
    if op == "flip":
        bit = rng.randrange(8)
        b[at] ^= 1 << bit
        return bytes(b), f"bit {bit} of byte {at} flipped"
    if op == "flips":
        n = rng.randint(2, 16)
        for _ in range(n):
            b[rng.randrange(lo, hi)] ^= 1 << rng.randrange(8)
        return bytes(b), f"{n} random bits flipped in bytes {lo}..{hi}"
    if op == "byte":
        v = rng.choice((0, 0xFF, 0x7F, 0x80, rng.randrange(256)))
        b[at] = v
        return bytes(b), f"byte {at} set to {v:#x}"
    if op == "insert":
        n = rng.choice((1, 4, 8, 100))
        b[at:at] = bytes(rng.randrange(256) for _ in range(n))
        return bytes(b), f"{n} bytes inserted at {at}"
    if op == "delete":
        n = min(rng.choice((1, 4, 8, 100)), hi - at)
        del b[at : at + n]
        return bytes(b), f"{n} bytes removed at {at}"
    if op == "dup":
        n = min(rng.choice((4, 16, 64)), hi - at)
        b[at:at] = b[at : at + n]
        return bytes(b), f"bytes {at}..{at + n} duplicated"
    n = min(rng.choice((4, 8, 16)), (hi - lo) // 2)
    if n == 0:
        return bytes(b[:-1]), "last byte removed"
    i, j = sorted(rng.sample(range(lo, hi - n + 1), 2)) if hi - n + 1 - lo >= 2 else (lo, lo)
    if j - i < n:
        b[i], b[hi - 1] = b[hi - 1], b[i]
        return bytes(b), f"bytes {i} and {hi - 1} swapped"
    b[i : i + n], b[j : j + n] = b[j : j + n], b[i : i + n]
    return bytes(b), f"runs of {n} bytes at {i} and {j} swapped"


def reorder(items: Sequence[Any], rng: random.Random) -> tuple[list[Any], str]:
    """``items`` with two of them swapped, one dropped, or one duplicated."""
    out = list(items)
    op = rng.choice(("swap", "drop", "dup"))
    if op == "swap" and len(out) >= 2:
        i, j = rng.sample(range(len(out)), 2)
        out[i], out[j] = out[j], out[i]
        return out, f"items {i} and {j} swapped"
    if op == "drop" and out:
        i = rng.randrange(len(out))
        del out[i]
        return out, f"item {i} dropped"
    i = rng.randrange(len(out)) if out else 0
    out[i:i] = out[i : i + 1]
    return out, f"item {i} duplicated"


# -- JSON --------------------------------------------------------------------------------------

#: Replacement values of any JSON node: wrong types, edges of numbers (NaN and Infinity are the
#: tokens Python's json writes and reads), a 400-digit integer, deep nesting.
#: Stands for a list nested this deep; :func:`dumps` writes it out (json.dumps would recurse).
_DEEP = "\0deep-nesting-"


def dumps(doc: Any) -> str:
    """``json.dumps`` of a mutated document, with the deep nestings written out."""
    text = json.dumps(doc)
    for depth in (50, 5000):
        text = text.replace(json.dumps(f"{_DEEP}{depth}"), "[" * depth + "0" + "]" * depth)
    return text


def _replacements(rng: random.Random, old: Any) -> list[tuple[Any, str]]:
    depth = rng.choice((50, 5000))
    deep = f"{_DEEP}{depth}"
    out: list[tuple[Any, str]] = [
        (None, "null"), (True, "true"), (False, "false"), ("", "''"), ("x", "'x'"),
        ([], "[]"), ({}, "{}"), (0, "0"), (-1, "-1"), (1, "1"), (2**31, "2**31"),
        (2**64, "2**64"), (10**400, "a 400-digit integer"), (-(10**30), "-1e30 as int"),
        (1e300, "1e300"), (-1e300, "-1e300"), (1e-320, "1e-320"), (0.5, "0.5"),
        (float("nan"), "NaN"), (float("inf"), "Infinity"), (float("-inf"), "-Infinity"),
        (deep, f"a list nested {depth} deep"), ("../../escape", "'../../escape'"), ("a/b", "'a/b'"),
        ("\x00", "NUL string"), ("/dev/zero", "'/dev/zero'"),
    ]
    if isinstance(old, (int, float)) and not isinstance(old, bool):
        out += [(old * 1000, f"{old}*1000"), (-old, f"-{old}"), (old + 1, f"{old}+1"),
                (float(old) + 0.5, f"{old}+0.5")]
    if isinstance(old, list) and old:
        out += [(old * 50, "list repeated 50 times"), (old[:-1], "last item dropped"),
                (old + [old[-1]], "last item duplicated"), (list(reversed(old)), "reversed")]
    if isinstance(old, str):
        out += [(old + old, "string doubled"), (old[:-1], "string shortened"),
                (old.upper(), "string upper-cased")]
    return out


def _paths(doc: Any, prefix: tuple[Any, ...] = ()) -> list[tuple[Any, ...]]:
    """Every node path of ``doc`` (dict keys and list indices)."""
    out = [prefix]
    if isinstance(doc, dict):
        for k, v in doc.items():
            out += _paths(v, prefix + (k,))
    elif isinstance(doc, list):
        for i, v in enumerate(doc[:64]):  # big arrays: their first items stand for the rest
            out += _paths(v, prefix + (i,))
    return out


def _get(doc: Any, path: tuple[Any, ...]) -> Any:
    for p in path:
        doc = doc[p]
    return doc


def mutate_json(doc: Any, rng: random.Random, focus: Sequence[tuple[Any, ...]] = ()) -> tuple[Any, str]:
    """One mutation of a JSON document: a node replaced by a boundary or wrong-typed value, a
    key removed or added, an array reordered. ``focus`` (paths) gets half the draws."""
    doc = copy.deepcopy(doc)
    paths = _paths(doc)
    path = rng.choice(list(focus)) if focus and rng.random() < 0.5 else rng.choice(paths)
    try:
        node = _get(doc, path)
    except (KeyError, IndexError, TypeError):
        path, node = (), doc
    where = "/".join(str(p) for p in path) or "<root>"
    ops = ["replace", "replace", "replace"]
    if isinstance(node, dict):
        ops += ["delete_key", "add_key"]
    if isinstance(node, list) and node:
        ops += ["reorder"]
    op = rng.choice(ops)
    if op == "delete_key" and node:
        k = rng.choice(list(node))
        del node[k]
        return doc, f"{where}: key {k!r} removed"
    if op in ("add_key", "delete_key"):
        node["unexpected_key"] = 1
        return doc, f"{where}: unknown key added"
    if op == "reorder":
        new, what = reorder(node, rng)
        node[:] = new
        return doc, f"{where}: {what}"
    value, what = rng.choice(_replacements(rng, node))
    if not path:
        return value, f"document replaced by {what}"
    _get(doc, path[:-1])[path[-1]] = value
    return doc, f"{where} -> {what}"
