"""Tables of samples as other loggers write them: column names and units, delimiters, a
decimal comma, no header, numpy's commented header, gzip; and the errors when a table cannot
be read (what was wrong, what to write instead)."""
from __future__ import annotations

import gzip

import numpy as np
import pytest

from analysis import load, load_all
from analysis.records.columns import G0, ColumnError, map_header
from gateway.errors import DataError


@pytest.fixture(scope="module")
def samples():
    """A meander's samples in the analysis's units: t s, u %, y kgf, r kgf."""
    t = np.round(np.arange(0.0, 8.0, 0.002), 6)
    u = np.where(np.sin(2 * np.pi * t / 2.0) >= 0, 10.0, -10.0)
    y = 500.0 + np.cumsum(np.roll(u, 25)) * 120.0 * 0.002
    r = 400.0 * np.sin(2 * np.pi * 0.5 * t)
    return t, u, y, r


def _write(path, header, columns, delimiter=",", decimal_comma=False, fmt="%.9g"):
    lines = [] if header is None else [header]
    for row in zip(*columns):
        cells = [fmt % v for v in row]
        if decimal_comma:
            cells = [c.replace(".", ",") for c in cells]
        lines.append(delimiter.join(cells))
    text = "\n".join(lines) + "\n"
    if str(path).endswith(".gz"):
        with gzip.open(path, "wt") as fh:
            fh.write(text)
    else:
        path.write_text(text)
    return path


@pytest.mark.parametrize("name, header, scale, delimiter, decimal_comma", [
    ("plain.csv", "t,u,y,r", (1, 1, 1, 1), ",", False),
    ("units.csv", "time [ms],valve_command_pct,Force (kN),ref_N", (1e3, 1, 1e-3 * G0, G0), ",", False),
    ("volts.csv", "Time_s,u_V,force in N,setpoint [daN]", (1, 0.1, G0, G0 / 10), ",", False),
    ("excel.csv", "time [s];u [%];force [kgf];reference [kgf]", (1, 1, 1, 1), ";", True),
    ("tabs.tsv", "t\tu\ty\tr", (1, 1, 1, 1), "\t", False),
    ("blanks.txt", "# t u y r", (1, 1, 1, 1), " ", False),
    ("packed.csv.gz", "y,r,u,t", (1, 1, 1, 1), ",", False),
    ("noheader.dat", None, (1, 1, 1, 1), ",", False),
])
def test_a_table_in_any_common_layout_reads_as_the_same_samples(samples, tmp_path, name, header,
                                                                 scale, delimiter, decimal_comma):
    t, u, y, r = samples
    cols = [t * scale[0], u * scale[1], y * scale[2], r * scale[3]]
    if name == "packed.csv.gz":
        cols = [cols[2], cols[3], cols[1], cols[0]]
    rec = load(_write(tmp_path / name, header, cols, delimiter, decimal_comma))
    assert np.allclose(rec.t, t, atol=1e-9) and np.allclose(rec.u, u, atol=1e-6)
    assert np.allclose(rec.y, y, rtol=1e-7, atol=1e-6) and np.allclose(rec.r, r, rtol=1e-7, atol=1e-6)
    converted = [n for n in rec.notes if n.startswith("column ")]
    assert len(converted) == sum(s != 1 for s in scale), rec.notes
    assert any(n.startswith("no header") for n in rec.notes) == (header is None)


def test_columns_in_unknown_units_or_doubled_are_refused_with_what_to_write(tmp_path):
    with pytest.raises(ColumnError, match=r"'force_lbf' is in a unit not known for the force \(known: kgf"):
        map_header(["t", "u", "force_lbf"])
    with pytest.raises(ColumnError, match=r"force is in 2 columns \(y, force\); keep one"):
        map_header(["t", "u", "y", "force"])
    with pytest.raises(ColumnError, match=r"no time column: name it 't' or 'time'"):
        map_header(["x", "u", "y"])
    # a logger's extra channels are ignored, even one that starts like a signal's name
    columns, notes = map_header(["t", "u", "y", "y_counts", "spool", "temperature [C]"])
    assert {s: c.index for s, c in columns.items()} == {"t": 0, "u": 1, "y": 2} and notes == []
    _write(tmp_path / "five.csv", None, [np.arange(30.0)] * 5)
    with pytest.raises(DataError, match="no header and 5 columns"):
        load(tmp_path / "five.csv")
    (tmp_path / "bad.csv").write_text("t;u;y\n0;1;2\n0,002;x;3\n")
    with pytest.raises(DataError, match=r"bad.csv:3: 'x' is not a number"):
        load(tmp_path / "bad.csv")
    # blank-separated with blanks inside the names: they would slide onto the wrong columns
    (tmp_path / "slid.txt").write_text("time [s] u [%] force [kN]\n0 1 2\n0.002 1 3\n")
    with pytest.raises(DataError, match=r"header has 6 fields .* but the rows have 3"):
        load(tmp_path / "slid.txt")
    (tmp_path / "data.xlsx").write_text("")
    with pytest.raises(DataError, match=r"unknown input type; give a table of samples"):
        load(tmp_path / "data.xlsx")


def test_a_time_column_that_looks_like_milliseconds_is_said(samples, tmp_path):
    t, u, y, _ = samples
    rec = load_all([_write(tmp_path / "ms.csv", "t,u,y", [t * 1e3, u, y])])[0]
    assert any("2 s apart: if the time column is not in seconds" in n for n in rec.notes)
    rec = load(_write(tmp_path / "s.csv", "t,u,y", [t, u, y]))
    assert not any("apart" in n for n in rec.notes)


@pytest.mark.parametrize("name,delimiter", [("latin1.csv", ","), ("latin1.txt.gz", " ")])
def test_a_latin_1_table_from_a_windows_logger_is_read_with_a_note(tmp_path, samples, name, delimiter):
    """'µs' written as the single byte 0xB5 (ISO 8859-1/cp1252), not UTF-8's two: it used to
    be refused as 'cannot read'."""
    t, u, y, _ = samples
    text = "\n".join([f"time[µs]{delimiter}u{delimiter}force[kN]"]
                     + [f"{a * 1e6:.0f}{delimiter}{b:g}{delimiter}{c * G0 * 1e-3:.12g}"
                        for a, b, c in zip(t, u, y)]) + "\n"
    raw = text.encode("latin-1")
    assert b"\xb5" in raw and b"\xc2" not in raw
    path = tmp_path / name
    if name.endswith(".gz"):
        with gzip.open(path, "wb") as fh:
            fh.write(raw)
    else:
        path.write_bytes(raw)
    rec = load(path)
    assert np.allclose(rec.t, t) and np.allclose(rec.y, y, rtol=1e-7)
    assert any("read as Latin-1" in n for n in rec.notes)
    assert any("'time[µs]' read as time in µs" in n for n in rec.notes), rec.notes


@pytest.mark.parametrize("encoding", ["cp1251", "utf-8"])
def test_a_russian_table_as_the_stands_labs_write_it_is_read(tmp_path, samples, encoding):
    """'Время, с;Управление, %;Усилие, кН;Задание, кгс' with a decimal comma, from a Russian
    Windows logger (Windows-1251) or a Linux one (UTF-8): the names and units are known."""
    t, u, y, r = samples
    header = "Время, мс;Управление, В;Усилие, кН;Задание, кгс"
    rows = [f"{a * 1e3:.6g};{b / 10:g};{c * G0 * 1e-3:.12g};{d:.9g}".replace(".", ",")
            for a, b, c, d in zip(t, u, y, r)]
    raw = ("\r\n".join([header] + rows) + "\r\n").encode(encoding)
    path = tmp_path / "испытание.csv"
    path.write_bytes(raw)
    rec = load(path)
    assert np.allclose(rec.t, t) and np.allclose(rec.u, u)
    assert np.allclose(rec.y, y, rtol=1e-7) and np.allclose(rec.r, r, rtol=1e-7)
    assert any("'Усилие, кН' read as force in кН" in n for n in rec.notes), rec.notes
    assert any("'Время, мс' read as time in мс" in n for n in rec.notes), rec.notes
    legacy = [n for n in rec.notes if "not UTF-8" in n]
    assert legacy == (["the file is not UTF-8: read as Windows-1251 (Cyrillic)"]
                      if encoding == "cp1251" else [])


def test_a_german_latin_1_table_is_not_taken_for_cyrillic(tmp_path, samples):
    """Latin-1 letters in Western words ('Größe', 'Zeit [µs]') stay Latin-1, and the German
    names are known."""
    t, u, y, _ = samples
    header = "Zeit [µs];Ventil [%];Kraft [kN];Größe"
    rows = [f"{a * 1e6:.0f};{b:g};{c * G0 * 1e-3:.12g};1" for a, b, c in zip(t, u, y)]
    path = tmp_path / "Prüfung.csv"
    path.write_bytes(("\n".join([header] + rows) + "\n").encode("latin-1"))
    rec = load(path)
    assert np.allclose(rec.t, t) and np.allclose(rec.y, y, rtol=1e-7)
    assert any("read as Latin-1" in n for n in rec.notes), rec.notes
    with pytest.raises(ColumnError, match="no force column"):
        map_header(["Время, с", "Управление, %", "Усилие, фунт"])


def _export(path, header_lines, rows, encoding="utf-8", bom=False):
    """A table as a Windows program exports it: CRLF line ends, optionally a byte-order mark."""
    data = ("\r\n".join(header_lines + rows) + "\r\n").encode(encoding)
    path.write_bytes((b"\xef\xbb\xbf" if bom else b"") + data)
    return path


@pytest.mark.parametrize("encoding, bom", [("utf-8", False), ("utf-8", True), ("cp1251", False)])
@pytest.mark.parametrize("header, scale", [
    ("Время, мс;Управление, В;Усилие, кН", (1e3, 0.1, 1e-3 * G0)),
    ("Время, с;Управление, %;Усилие, кгс", (1, 1, 1)),
    ("Время;Управление;Усилие", (1, 1, 1)),
    (None, (1, 1, 1)),
])
def test_a_semicolon_table_with_a_decimal_comma_in_every_value_is_read(tmp_path, samples, encoding,
                                                                       bom, header, scale):
    # every value has exactly one comma, so the comma splits every line alike too: the
    # semicolon must win because its header names the signals and its fields are numbers
    t, u, y, _ = samples
    rows = [";".join(f"{v:.4f}".replace(".", ",") for v in (a * scale[0], b * scale[1], c * scale[2]))
            for a, b, c in zip(t, u, y)]
    if encoding == "cp1251" and bom:
        pytest.skip("a byte-order mark is UTF-8's")
    rec = load(_export(tmp_path / "lab.csv", [header] if header else [], rows, encoding, bom))
    assert np.allclose(rec.t, t, atol=1e-6) and np.allclose(rec.u, u, atol=1e-3)
    assert np.allclose(rec.y, y, rtol=1e-4, atol=0.01)


def test_an_excel_export_with_a_trailing_empty_column_is_read(tmp_path, samples):
    t, u, y, _ = samples
    rows = [f"{a:.3f};{b:.3f};{c:.3f};".replace(".", ",") for a, b, c in zip(t, u, y)]
    rec = load(_export(tmp_path / "export.csv", ["time;command;force;"], rows + [";;;", ""], bom=True))
    assert len(rec) == len(t) and np.allclose(rec.y, y, atol=1e-3)


def test_a_logger_tsv_with_a_units_row_under_the_header_is_read_in_those_units(tmp_path, samples):
    t, u, y, _ = samples
    rows = [f"{a * 1e3:.3f}\t{b / 10:.5f}\t{c * G0 / 1e3:.6f}" for a, b, c in zip(t, u, y)]
    rec = load(_export(tmp_path / "logger.tsv", ["time\tcommand\tforce", "ms\tV\tkN"], rows, bom=True))
    assert np.allclose(rec.t, t, atol=1e-6) and np.allclose(rec.u, u, atol=1e-3)
    assert np.allclose(rec.y, y, rtol=1e-5, atol=0.01)
    assert any("kN" in n for n in rec.notes) and any("ms" in n for n in rec.notes)


@pytest.mark.parametrize("sep_line", ["sep=;", '"sep=;"', "SEP=;"])
def test_an_excel_csv_that_names_its_delimiter_in_its_first_line_is_read(tmp_path, samples, sep_line):
    """Excel writes 'sep=;' as the first line of a CSV (and reads the file back by it): it was
    taken for the header ('no time column ... (header: sep=,)')."""
    t, u, y, r = samples
    rows = [f"{a:.3f};{b:.3f};{c:.3f};{d:.3f}".replace(".", ",") for a, b, c, d in zip(t, u, y, r)]
    rec = load(_export(tmp_path / "excel.csv", [sep_line, "time [s];command [%];force [kgf];reference"],
                       rows, bom=True))
    assert len(rec) == len(t) and np.allclose(rec.t, t) and np.allclose(rec.u, u)
    assert np.allclose(rec.y, y, atol=1e-3) and np.allclose(rec.r, r, atol=1e-3)
    # the delimiter it names wins, even where another would split the lines alike
    rows = [f"{a:.3f},{b:.3f},{c:.3f}" for a, b, c in zip(t, u, y)]
    rec = load(_export(tmp_path / "comma.csv", ["sep=,", "t,u,y"], rows))
    assert np.allclose(rec.y, y, atol=1e-3)


def test_a_table_whose_time_starts_again_is_refused_with_where_and_what_to_do(tmp_path, samples):
    """Two runs written one after the other (the time restarts at 0), or a logger's clock set
    back: the rows were sorted by time and the repeated times dropped, which kept one run and
    lost the other without a word, or interleaved the two."""
    t, u, y, _ = samples
    two = _write(tmp_path / "two.csv", "t,u,y", [np.r_[t, t + 0.001], np.r_[u, -u], np.r_[y, y + 100]])
    with pytest.raises(DataError, match=r"two.csv: the time goes back from 7.998 s to 0.001 s at "
                                        r"sample 4001 of 8000: two runs in one file.*Give each run a "
                                        r"file of its own"):
        load(two)
    stepped = t.copy()
    stepped[2000:] -= 0.5
    with pytest.raises(DataError, match="goes back from 3.998 s to 3.5 s at sample 2001"):
        load(_write(tmp_path / "clock.csv", "t,u,y", [stepped, u, y]))
    # a few rows out of order and a repeated time are only tidied
    order = np.arange(len(t))
    order[[100, 101]] = [101, 100]
    dup = np.r_[order[:300], 299, order[300:]]
    rec = load(_write(tmp_path / "swapped.csv", "t,u,y", [t[dup], u[dup], y[dup]]))
    assert np.array_equal(rec.t, t) and np.array_equal(rec.y, np.round(y, 6))
    assert any("time was not increasing: sorted, dropped 1 duplicate" in n for n in rec.notes), rec.notes
