"""Vectorised decimal formatting: millions of numbers to text without a Python loop.

Exporters write one text record per tree (RIB instance files) or long lists of
numbers (RIB archives), each a fixed *template* of constant byte strings and
numeric fields.  Python's ``%``/f-string formatting costs 0.2–0.5 µs per number,
i.e. several seconds for a million trees; here the digits of a whole block of
rows are produced at once with numpy:

1. a value x with ``d`` decimals becomes the integer q = round(|x|·10^d)
   (or floor/ceil, for bounds that must stay conservative);
2. q's integer and fraction parts are split into base-10⁴ groups
   (q mod 10⁴, ⌊q/10⁴⌋ mod 10⁴, …) and each group is looked up in a
   10 000-entry table of four ASCII digits packed in a uint32, so a 12-digit
   number costs three integer divisions and three gathers instead of twelve;
3. the fields and the constant segments are laid side by side in one
   ``(rows, width)`` byte matrix.

Two layouts:

* **trimmed** (:func:`format_rows`, :func:`format_numbers`) — the shortest
  fixed-point text, as ``f"{x:.{d}f}"`` with trailing zeros (and a bare
  decimal point) removed, e.g. ``-0.5``, ``12``, ``3.25``: leading zeros,
  trailing zeros and unused sign slots become *holes* (NUL bytes) chosen by
  alternative lookup tables, and the flattened matrix is stripped of them;
* **fixed width** (:class:`RowWriter`, ``Field(pad=True)``) — leading zeros
  become spaces, the sign sits just before the first digit and the fraction
  keeps all ``d`` digits; no byte needs removing, so a block's matrix goes to
  the file as it is.  Used for the per-tree records, where the strip pass
  would cost as much as the formatting.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

HOLE = 0
MAX_ABS_INT = 2**62


class Field:
    """A block of numeric columns of a template: ``values (rows, k)``, ``decimals``.

    Each number is written with one leading space (``sep=True``) so that
    consecutive fields separate, or every number but the first
    (``sep="inner"``); floor/ceil rounding is available for bounds that must
    stay conservative.

    With ``pad=True`` the number is written at a fixed width instead —
    leading zeros become spaces (the sign moves next to the first digit) and
    the fraction keeps all ``decimals`` digits — so the row needs no
    compaction; ``int_digits`` then fixes the width of the integer part
    independently of the data in one block (callers size it from the whole
    data set, so the text does not depend on how rows are split into blocks);
    every number then keeps its separator space, ``"inner"`` included.
    """

    def __init__(
        self,
        values: np.ndarray,
        decimals: int = 0,
        *,
        sep: bool | str = True,
        rounding: str = "nearest",
        pad: bool = False,
        int_digits: int | None = None,
    ):
        v = np.asarray(values)
        if v.ndim == 1:
            v = v[:, None]
        self.values = v
        self.decimals = int(decimals)
        self.sep = sep
        self.rounding = rounding
        self.pad = pad
        self.int_digits = int_digits


class LeftInt:
    """Non-negative integers written left-aligned, followed by ``suffix`` and padding spaces.

    For names inside strings (``"tree_123"]``) where padding must come after
    the closing quote: row text = digits + suffix + spaces, of fixed width.
    """

    def __init__(self, values: np.ndarray, suffix: bytes, digits: int):
        self.values = np.asarray(values).astype(np.int64).reshape(-1)
        if self.values.size and (self.values.min() < 0 or len(str(int(self.values.max()))) > digits):
            raise ValueError("integer out of range of its field")
        self.suffix = suffix
        self.digits = int(digits)


Segment = bytes | Field | LeftInt


def _scaled(values: np.ndarray, decimals: int, rounding: str) -> tuple[np.ndarray, np.ndarray]:
    """Integers q = round(|x|·10^d) (int64) and the sign mask of the written value."""
    if np.issubdtype(values.dtype, np.integer):
        if decimals:
            raise ValueError("integer fields take no decimals")
        v = values.astype(np.int64)
        return np.abs(v), v < 0
    x = values.astype(np.float64) * (10.0**decimals)
    if not np.isfinite(x).all():
        raise ValueError("cannot write NaN or infinite values")
    if rounding == "floor":
        x = np.floor(x)
    elif rounding == "ceil":
        x = np.ceil(x)
    else:
        x = np.rint(x)
    if x.size and np.abs(x).max() >= MAX_ABS_INT:
        raise ValueError(f"value too large to write with {decimals} decimals")
    q = x.astype(np.int64)
    return np.abs(q), q < 0


def _table(strings) -> np.ndarray:
    """4-byte strings (holes as NUL) packed into uint32 so a gather yields text bytes."""
    return np.frombuffer(b"".join(strings), dtype="<u4").copy()


_FULL = [f"{i:04d}".encode() for i in range(10000)]
# Fraction groups: trailing zeros become holes (group 0 → four holes).
_TRAIL = [f"{i:04d}".rstrip("0").encode().ljust(4, b"\0") for i in range(10000)]
# Integer groups left of the first non-zero digit: leading zeros become holes;
# the group holding the units digit keeps at least that digit.
_LEAD = [f"{i:04d}".lstrip("0").encode().rjust(4, b"\0") for i in range(10000)]
_UNITS = [b"\0\0\0" + b"0"] + _LEAD[1:]
_FRAC_TABLE = _table(_FULL + _TRAIL)  # index: g + 10⁴·(all groups to the right are 0)
_INT_TABLE = _table(_FULL + _LEAD + _FULL + _UNITS)  # index: g + 10⁴·(left all 0) + 2·10⁴·(units group)


def _groups(v: np.ndarray, n: int) -> list[np.ndarray]:
    """Base-10⁴ digits of ``v``, most significant first (n groups)."""
    out = []
    for _ in range(n - 1):
        v, g = np.divmod(v, 10000)
        out.append(g)
    out.append(v)
    return out[::-1]


def _layout(field: Field):
    q, neg = _scaled(field.values, field.decimals, field.rounding)
    d = field.decimals
    top = int(q.max()) if q.size else 0
    n_int = max(1, len(str(top // 10**d)))
    gi = math.ceil(n_int / 4)
    gf = math.ceil(d / 4)
    W = int(bool(field.sep)) + 1 + 4 * gi + (1 + 4 * gf if d else 0)
    return (q, neg, gi, gf), W


def _integer_groups(ip: np.ndarray, gi: int, table: np.ndarray) -> np.ndarray:
    """Integer parts as ``gi`` 4-character groups (uint32 each), most significant first.

    ``table`` is indexed by group value + 10000 while every group to the left
    is zero (leading-zero form) + 20000 for the last group (which always shows
    a digit).
    """
    ints = np.empty((*ip.shape, gi), dtype=np.uint32)
    left_zero = np.ones(ip.shape, dtype=bool)
    for j, g in enumerate(_groups(ip, gi)):
        idx = g + np.where(left_zero, 10000, 0)
        if j == gi - 1:
            idx += 20000
        ints[..., j] = table[idx]
        left_zero &= g == 0
    return ints


def _write_field(field: Field, out: np.ndarray, layout) -> None:
    """Write the text of ``field`` into ``out`` (rows, k, W) uint8; holes = 0.

    Layout of a number: [space] [sign] [4·gi integer digits] [. 4·gf fraction digits].
    """
    q, neg, gi, gf = layout
    d = field.decimals
    rows, k = field.values.shape
    o = int(bool(field.sep))
    if field.sep:
        out[..., 0] = 32
        if field.sep == "inner":
            out[:, 0, 0] = HOLE
    out[..., o] = np.where(neg, 45, HOLE)
    if d:
        ip, fp = np.divmod(q, 10**d)
        fp = fp * 10 ** (4 * gf - d)  # left-align the fraction in whole groups
    else:
        ip, fp = q, None
    # integer groups, left to right
    ints = _integer_groups(ip, gi, _INT_TABLE)
    out[..., o + 1 : o + 1 + 4 * gi] = ints.view(np.uint8).reshape(rows, k, 4 * gi)
    if not d:
        return
    fr = np.empty((rows, k, gf), dtype=np.uint32)
    right_zero = np.ones((rows, k), dtype=bool)
    groups = _groups(fp, gf)
    for j in range(gf - 1, -1, -1):
        g = groups[j]
        fr[..., j] = _FRAC_TABLE[g + np.where(right_zero, 10000, 0)]
        right_zero &= g == 0
    out[..., o + 1 + 4 * gi] = np.where(right_zero, HOLE, 46)
    out[..., o + 2 + 4 * gi :] = fr.view(np.uint8).reshape(rows, k, 4 * gf)


_SPACE_LEAD = [f"{i:04d}".lstrip("0").encode().rjust(4, b" ") for i in range(10000)]
_SPACE_UNITS = [b"   0"] + _SPACE_LEAD[1:]
_PAD_TABLE = _table(_FULL + _SPACE_LEAD + _FULL + _SPACE_UNITS)  # same index as _INT_TABLE
_FULL_TABLE = _table(_FULL)


def _digits_of(v: np.ndarray, top: int) -> np.ndarray:
    """Decimal digit count of non-negative integers (0 has one)."""
    n = np.ones(v.shape, dtype=np.int64)
    p = 10
    while p <= top:
        n += v >= p
        p *= 10
    return n


def _pad_layout(field: Field):
    q, neg = _scaled(field.values, field.decimals, field.rounding)
    d = field.decimals
    top_int = int(q.max()) // 10**d if q.size else 0
    n_int = max(1, len(str(top_int)))
    if field.int_digits is not None:
        if n_int > field.int_digits:
            raise ValueError(f"value needs {n_int} integer digits, the field has {field.int_digits}")
        n_int = field.int_digits
    W = int(bool(field.sep)) + 1 + n_int + (1 + d if d else 0)
    return (q, neg, n_int), W


def _write_padded(field: Field, out: np.ndarray, layout) -> None:
    """Fixed-width text of ``field`` into ``out`` (rows, k, W): [space][sign+digits][.digits]."""
    q, neg, n_int = layout
    d = field.decimals
    rows, k = field.values.shape
    o = int(bool(field.sep))
    if field.sep:
        out[..., 0] = 32
    if d:
        ip, fp = np.divmod(q, 10**d)
    else:
        ip, fp = q, None
    gi = math.ceil(n_int / 4)
    ints = _integer_groups(ip, gi, _PAD_TABLE)
    region = out[..., o : o + 1 + n_int]
    region[..., 0] = 32
    region[..., 1:] = ints.view(np.uint8).reshape(rows, k, 4 * gi)[..., 4 * gi - n_int :]
    if neg.any():  # the sign goes just before the first digit
        pos = np.where(neg, n_int - _digits_of(ip, 10**n_int), -1)
        for p in range(n_int):
            hit = pos == p
            if hit.any():
                region[..., p][hit] = 45
    if d:
        gf = math.ceil(d / 4)
        fp = fp * 10 ** (4 * gf - d)
        fr = np.empty((rows, k, gf), dtype=np.uint32)
        for j, g in enumerate(_groups(fp, gf)):
            fr[..., j] = _FULL_TABLE[g]
        out[..., o + 1 + n_int] = 46
        out[..., o + 2 + n_int :] = fr.view(np.uint8).reshape(rows, k, 4 * gf)[..., :d]


def _write_left_int(seg: LeftInt, out: np.ndarray) -> None:
    v = seg.values
    T = seg.digits
    g = math.ceil(T / 4)
    chars = np.empty((len(v), g), dtype=np.uint32)
    for j, grp in enumerate(_groups(v, g)):
        chars[:, j] = _FULL_TABLE[grp]
    digits = chars.view(np.uint8).reshape(len(v), 4 * g)[:, 4 * g - T :]
    S = len(seg.suffix)
    src = np.empty((len(v), 2 * T + S), dtype=np.uint8)
    src[:, :T] = digits
    src[:, T : T + S] = np.broadcast_to(np.frombuffer(seg.suffix, np.uint8), (len(v), S))
    src[:, T + S :] = 32
    shift = (T - _digits_of(v, 10**T))[:, None]
    out[:] = np.take_along_axis(src, shift + np.arange(T + S), axis=1)


def _plan(template: Sequence[Segment], rows: int) -> tuple[list[tuple[Any, Any, int, int]], int]:
    plan: list[tuple[Any, Any, int, int]] = []
    width = 0
    for s in template:
        if isinstance(s, Field):
            if not s.pad:
                raise ValueError("fixed-width rows need padded fields")
            if len(s.values) != rows:
                raise ValueError("fields of one template must have the same number of rows")
            layout, W = _pad_layout(s)
            plan.append((s, layout, width, W * s.values.shape[1]))
            width += W * s.values.shape[1]
        elif isinstance(s, LeftInt):
            if len(s.values) != rows:
                raise ValueError("fields of one template must have the same number of rows")
            plan.append((s, None, width, s.digits + len(s.suffix)))
            width += s.digits + len(s.suffix)
        else:
            if HOLE in s:
                raise ValueError("constant segments cannot contain NUL bytes")
            plan.append((s, None, width, len(s)))
            width += len(s)
    return plan, width


def _fill(plan, buf: np.ndarray) -> None:
    rows = buf.shape[0]
    for s, layout, off, W in plan:
        view = buf[:, off : off + W]
        if isinstance(s, Field):
            k = s.values.shape[1]
            _write_padded(s, view.reshape(rows, k, W // k), layout)
        elif isinstance(s, LeftInt):
            _write_left_int(s, view)
        else:
            view[:] = np.broadcast_to(np.frombuffer(s, dtype=np.uint8), (rows, W))


class RowWriter:
    """Streams blocks of fixed-width rows to a binary file through one reused buffer.

    Every :class:`Field` must be ``pad=True``: with no holes to strip, a block's
    byte matrix goes to the file as it is.  (Formatting the next block on a
    second thread while one is written was measured slower on a busy 2-core
    machine, so blocks are written in line.)
    """

    def __init__(self, fh):
        self.fh = fh
        self.buffer = np.empty(0, dtype=np.uint8)
        self.written = 0

    def write(self, template: Sequence[Segment], rows: int) -> int:
        """Format ``rows`` records of ``template`` and write them; returns their bytes."""
        if rows == 0:
            return 0
        plan, width = _plan(template, rows)
        n = rows * width
        if self.buffer.size < n:  # fresh pages cost about as much as filling them: reuse
            self.buffer = np.empty(n, dtype=np.uint8)
        buf = self.buffer[:n].reshape(rows, width)
        _fill(plan, buf)
        self.fh.write(buf)
        self.written += n
        return n

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.buffer = np.empty(0, dtype=np.uint8)


def write_rows(fh, template: Sequence[Segment], rows: int) -> int:
    """Write ``rows`` fixed-width records to the binary file ``fh`` at once; returns bytes written."""
    with RowWriter(fh) as w:
        return w.write(template, rows)


def format_rows(template: Sequence[Segment], rows: int | None = None) -> bytes:
    """Render ``rows`` records of ``template`` (constants and :class:`Field` blocks) to bytes.

    All fields must have the same number of rows; constants repeat on every row.
    """
    if rows is None:
        rows = next(len(s.values) for s in template if isinstance(s, Field))
    if rows == 0:
        return b""
    plan: list[tuple[Any, Any, int, int]] = []
    width = 0
    for s in template:
        if isinstance(s, Field):
            if len(s.values) != rows:
                raise ValueError("fields of one template must have the same number of rows")
            layout, W = _layout(s)
            plan.append((s, layout, width, W))
            width += W * s.values.shape[1]
        else:
            assert isinstance(s, bytes), "fixed-width layouts only: LeftInt needs padded fields"
            if HOLE in s:
                raise ValueError("constant segments cannot contain NUL bytes")
            plan.append((s, None, width, len(s)))
            width += len(s)
    buf = np.empty((rows, width), dtype=np.uint8)
    for s, layout, off, W in plan:
        if layout is None:
            buf[:, off : off + W] = np.broadcast_to(np.frombuffer(s, dtype=np.uint8), (rows, W))
        else:
            k = s.values.shape[1]
            _write_field(s, buf[:, off : off + W * k].reshape(rows, k, W), layout)
    return buf.tobytes().translate(None, b"\0")


def format_numbers(values: np.ndarray, decimals: int, *, per_line: int = 0, indent: bytes = b"") -> bytes:
    """A flat list of numbers, space separated, ``per_line`` values per line (0: one line).

    Used for long RIB arrays (vertex positions, indices); every line after the
    first starts with ``indent``.
    """
    v = np.asarray(values).ravel()
    if v.size == 0:
        return b""
    if per_line <= 0 or per_line >= v.size:
        return format_rows([Field(v[None, :], decimals, sep="inner")], 1)
    full = v.size // per_line
    out = format_rows(
        [indent, Field(v[: full * per_line].reshape(full, per_line), decimals, sep="inner"), b"\n"], full
    )[len(indent) :]
    rest = v[full * per_line :]
    if rest.size:
        out += indent + format_rows([Field(rest[None, :], decimals, sep="inner")], 1)
    else:
        out = out[:-1]
    return out


def fmt(x: float, decimals: int = 6) -> str:
    """One number as :func:`format_rows` writes it (for headers and small calls)."""
    return format_rows([Field(np.array([[x]], dtype=np.float64), decimals, sep=False)], 1).decode()
