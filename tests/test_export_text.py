"""The vectorised number formatter behind the exporters."""

import numpy as np
import pytest

from forest.export.text import Field, fmt, format_numbers, format_rows


def reference(x: float, d: int) -> str:
    s = f"{x:.{d}f}"
    if d:
        s = s.rstrip("0").rstrip(".")
    return "0" if s in ("-0", "") else s


@pytest.mark.parametrize("d", [0, 1, 3, 6, 7, 9])
def test_matches_python_fixed_point(d):
    rng = np.random.default_rng(d)
    x = np.concatenate(
        [
            rng.normal(size=400) * 10.0 ** rng.integers(-8, 6, 400),
            [0.0, -0.0, 1.0, -1.0, 0.5, 10.0, 1e5, -99999.5, 123456789.0, 1e-12, -1e-12],
        ]
    )
    x = x[np.abs(x) * 10**d < 2**52]
    text = format_rows([b"<", Field(x[:, None], d, sep=False), b">\n"]).decode()
    got = [t[1:-1] for t in text.splitlines()]
    want = [reference(v, d) for v in x]
    # Python rounds the exact binary value; we round x·10^d: they may differ by one unit
    # in the last place only where x·10^d sits within float error of a half-way point.
    bad = [(g, w) for g, w in zip(got, want) if g != w and abs(float(g) - float(w)) > 1.01 * 10.0**-d]
    assert not bad
    assert sum(g == w for g, w in zip(got, want)) >= 0.99 * len(x)
    assert np.allclose([float(g) for g in got], x, atol=0.5 * 10.0**-d * (1 + 1e-9), rtol=1e-15)


def test_fields_separate_and_rows_repeat_constants():
    rows = format_rows(
        [
            b"A",
            Field(np.array([[1.5, -2.0], [0.0, 3.25]]), 2, sep="inner"),
            b"|",
            Field(np.array([7, 12345678901], dtype=np.int64), 0),
            b"\n",
        ]
    ).decode()
    assert rows == "A1.5 -2| 7\nA0 3.25| 12345678901\n"


def test_floor_and_ceil_rounding_keep_bounds_outside():
    x = np.array([[-1.23456789, 1.23456711]])
    lo = format_rows([Field(x, 6, sep=False, rounding="floor")], 1).decode()
    hi = format_rows([Field(x, 6, sep=False, rounding="ceil")], 1).decode()
    assert lo.startswith("-1.234568") and hi.startswith("-1.234567")
    assert float(lo.split("1.234568")[0] + "1.234568") <= x[0, 0]


def test_format_numbers_wraps_lines():
    assert format_numbers(np.arange(7), 0, per_line=3, indent=b"  ") == b"0 1 2\n  3 4 5\n  6"
    assert format_numbers(np.arange(6), 0, per_line=3, indent=b"  ") == b"0 1 2\n  3 4 5"
    assert format_numbers(np.array([]), 0) == b""
    assert fmt(2.50, 3) == "2.5" and fmt(-0.0001, 3) == "0"


def test_rejects_non_finite():
    with pytest.raises(ValueError):
        format_rows([Field(np.array([[np.nan]]), 3)], 1)


def test_padded_rows_are_fixed_width_and_exact():
    import io

    from forest.export.text import LeftInt, write_rows

    rng = np.random.default_rng(4)
    x = np.clip(rng.normal(size=(500, 3)) * np.array([1.0, 30.0, 300.0]), -999, 999)
    ids = rng.integers(0, 10**7, 500)
    fh = io.BytesIO()
    n = write_rows(fh, [b'["t_', LeftInt(ids, b'"]', 7), Field(x, 4, pad=True, int_digits=3), b"\n"], len(x))
    lines = fh.getvalue().decode().splitlines()
    assert n == len(fh.getvalue()) and len({len(l) for l in lines}) == 1
    for line, i, row in zip(lines, ids, x):
        name, rest = line.split('"]')
        assert name == f'["t_{i}'
        assert [float(t) for t in rest.split()] == [float(f"{v:.4f}") for v in row]
    with pytest.raises(ValueError):
        write_rows(io.BytesIO(), [Field(np.array([[12345.0]]), 1, pad=True, int_digits=3)], 1)
