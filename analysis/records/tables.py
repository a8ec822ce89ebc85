"""Tables of samples in and out: a table ``t,u,y[,r]`` (s, %, kgf; other column names and units
are recognised, :mod:`analysis.records.columns`) as other loggers write it — its text encoding,
delimiter, decimal mark, header and row of units told from the file — read into a
:class:`~analysis.records.record.Record`, and a record written back as CSV.
"""
from __future__ import annotations

import csv
import gzip
import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from gateway.errors import DataError

from ..defaults import TABLE_SUFFIXES  # noqa: F401 (re-exported)

from .columns import ColumnError, map_header, positional, written_unit
from .record import Record, make_record

#: a sampling interval (s) beyond which the time column is suspected to be in another unit
SLOW_SAMPLING_S = 0.1
_DELIMITERS = (",", ";", "\t")
_DECIMAL_COMMA = re.compile(r"^[-+]?\d+,\d+(?:[eE][-+]?\d+)?$")
#: Excel's first line naming the delimiter: ``sep=;`` (quoted by some exporters)
_SEP_LINE = re.compile(r'^"?sep=(.)"?\s*$', re.IGNORECASE)


@dataclass(frozen=True)
class _Layout:
    """How a table file is written: its delimiter (None: runs of blanks), its decimal mark,
    whether its first line is a header, and the first line's fields."""
    delimiter: str | None
    decimal: str
    has_header: bool
    first: list[str]
    encoding: str = "utf-8-sig"
    #: lines before the data: the header, and a row of units under it if there is one
    skip: int = 0


#: bytes read to tell the text encoding
_SNIFF_BYTES = 1 << 20


def open_path(path: Path, mode: str, **kwargs):
    """``path`` opened in ``mode`` ("rb", "rt"), through gzip if it ends in ``.gz``."""
    return (gzip.open(path, mode, **kwargs) if path.suffix.lower() == ".gz"
            else path.open(mode, **kwargs))


def type_suffix(path: Path) -> str:
    """The file's type suffix, lower case, ``.gz`` looked through (``"a.CSV.gz"`` -> ``.csv``;
    ``""``: none)."""
    suffixes = [s.lower() for s in path.suffixes]
    if suffixes and suffixes[-1] == ".gz":
        suffixes = suffixes[:-1]
    return suffixes[-1] if suffixes else ""


#: the encodings a table that is not UTF-8 is read in, and how the note names them
_LEGACY_ENCODINGS = {"cp1251": "Windows-1251 (Cyrillic)", "latin-1": "Latin-1 (ISO 8859-1)"}
# three or more bytes in a row from 0xC0-0xFF: a Cyrillic word in Windows-1251 ("Время" is
# C2 F0 E5 EC FF); in Latin-1 they would be three accented letters in a row, which Western
# words hardly have
_CYRILLIC_RUN = re.compile(rb"[\xC0-\xFF]{3,}")
_HIGH_BYTES = re.compile(rb"[\x80-\xFF]+")


def _encoding(path: Path) -> str:
    """UTF-8 (with or without a byte-order mark) if the file's start decodes as such; else
    Windows-1251 if its non-ASCII bytes are mostly runs of Cyrillic letters (a Russian
    Windows logger: 'Время, с;Усилие, кгс'), else Latin-1 (a Western one: 'Kraft [kN]',
    'Zeit [µs]' in cp1252/ISO 8859-1)."""
    with open_path(path, "rb") as fh:
        head = fh.read(_SNIFF_BYTES)
    try:
        head.decode("utf-8")
    except UnicodeDecodeError as exc:
        if exc.start < len(head) - 3:   # not a character cut at the sniffed length
            high = sum(len(m) for m in _HIGH_BYTES.findall(head))
            in_words = sum(len(m) for m in _CYRILLIC_RUN.findall(head))
            return "cp1251" if in_words * 2 > high else "latin-1"
    return "utf-8-sig"


def _open_text(path: Path, encoding: str = "utf-8-sig"):
    return open_path(path, "rt", newline="", encoding=encoding)


def _split(line: str, delimiter: str | None) -> list[str]:
    return line.split() if delimiter is None else next(csv.reader([line], delimiter=delimiter))


def _decimal_mark(fields: list[str], delimiter: str | None) -> str:
    """',' if the fields (split by ``delimiter``) hold decimal commas (``1,5``), else '.'."""
    return "," if delimiter != "," and any(_DECIMAL_COMMA.match(f.strip()) for f in fields) else "."


def _is_number(text: str, decimal: str) -> bool:
    try:
        float(text.replace(",", ".") if decimal == "," else text)
        return True
    except ValueError:
        return False


def _choose_delimiter(lines: list[str]) -> str | None:
    """The delimiter of a table from its first lines (None: runs of blanks).

    A candidate must split every sniffed line into the same number of fields. Among those, the
    one whose header names the signals and whose data fields are all numbers wins; then the
    more frequent one. Both matter: 'Время, с;Усилие, кгс' has more commas than semicolons,
    and with decimal commas ('0,0;1,000;9,8067') the comma splits every line alike too."""
    rows = [ln.rstrip("\r\n") for ln in lines]
    counts = {d: rows[0].count(d) for d in _DELIMITERS if rows[0].count(d)}
    if not counts:
        return None
    consistent = [d for d in counts if len({len(_split(r, d)) for r in rows}) == 1]

    def score(d: str) -> tuple[bool, bool, int]:
        data = [f.strip() for r in rows[1:] or rows for f in _split(r, d)]
        decimal = _decimal_mark(data, d)
        numeric = all(_is_number(f, decimal) for f in data if f)
        first = [f.strip() for f in _split(rows[0].lstrip("#"), d)]
        try:
            named = all(_is_number(f, decimal) for f in first if f) or bool(map_header(first)[0])
        except ColumnError:
            named = False
        return named and numeric, numeric, counts[d]

    return max(consistent or counts, key=score)


def _layout(path: Path) -> _Layout:
    """Sniff the delimiter (comma, semicolon, tab, else blanks), a decimal comma (``1,5;2,25``)
    and whether the first line is a header (it is unless every field is a number; a leading
    ``#`` is taken off it). Later lines starting with ``#`` are comments. A first line
    ``sep=;`` (Excel writes it, and reads the file back by it) gives the delimiter."""
    try:
        encoding = _encoding(path)
        with _open_text(path, encoding) as fh:
            lines = [ln for ln in (fh.readline() for _ in range(5)) if ln.strip()]
    except (OSError, UnicodeDecodeError, EOFError) as exc:
        raise DataError(f"cannot read {path}: {exc}") from None
    declared = _SEP_LINE.match(lines[0].rstrip("\r\n")) if lines else None
    if declared:
        lines = lines[1:]
    else:
        lines = lines[:4]
    if not lines:
        raise DataError(f"{path}: empty file")
    delimiter = declared.group(1) if declared else _choose_delimiter(lines)
    # numpy's savetxt writes its header as a comment: "# t,u,y"
    first = [f.strip() for f in _split(lines[0].lstrip("#").rstrip("\r\n"), delimiter)]
    data = _split(lines[-1].rstrip("\r\n"), delimiter)
    decimal = _decimal_mark(data, delimiter)

    def number(text: str) -> bool:
        return _is_number(text, decimal)

    has_header = not all(number(f) for f in first if f)
    skip = int(has_header)
    if has_header and len(lines) > 2:
        units = [f.strip() for f in _split(lines[1].rstrip("\r\n"), delimiter)]
        if len(units) == len(first) and any(units) and not any(number(f) for f in units if f):
            # a logger's row of units under the names ("time;force" then "s;kN"): each unit
            # joins its name as the header would have written it ("force [kN]")
            first = [f"{name} [{unit}]" if unit and written_unit(name) is None else name
                     for name, unit in zip(first, units)]
            skip = 2
    if has_header and delimiter is None and len(lines) > 1 and len(first) != len(data):
        # blank-separated with "time [s]" in the header: the names would slide onto the
        # wrong columns
        raise DataError(f"{path}: the header has {len(first)} fields ({', '.join(first)}) but the "
                        f"rows have {len(data)}; in a blank-separated table write each name "
                        "without blanks, e.g. 'time_ms' not 'time [ms]'")
    return _Layout(delimiter, decimal, has_header, first, encoding, skip + int(bool(declared)))


def read_csv(path: str | Path) -> Record:
    """A table of samples: time, valve command, force and optionally the force reference.

    Comma, semicolon, tab or blank separated, a decimal comma recognised; the header names the
    columns and may give their units (``time [ms]``, ``force_N``, ``u_V``: see
    :mod:`analysis.records.columns`), which are converted to s, %, kgf with a note; a table without a
    header is read as t,u,y[,r] in that order, also with a note.

    Read with pyarrow's multi-threaded CSV reader (an hour at 500 Hz in well under a second);
    a file it refuses is read again line by line, so the error names the line and the value."""
    path = Path(path)
    layout = _layout(path)
    try:
        if layout.has_header:
            columns, notes = map_header(layout.first)
        else:
            columns = positional(len(layout.first))
            notes = [f"no header: the {len(columns)} columns read as {','.join(columns)} "
                     "(s, % of the full valve command, kgf)"]
    except ColumnError as exc:
        raise DataError(f"{path}: {exc}") from None
    if layout.encoding in _LEGACY_ENCODINGS:
        notes.append(f"the file is not UTF-8: read as {_LEGACY_ENCODINGS[layout.encoding]}")
    cols = None
    if layout.delimiter is not None:
        cols = _read_table_arrow(path, layout, columns)
    if cols is None:
        cols = _read_table_lines(path, layout, columns)
    cols = {c: v * columns[c].scale if columns[c].scale != 1.0 else v for c, v in cols.items()}
    rec = make_record(cols["t"], cols["u"], cols["y"], cols.get("r"), source=str(path))
    dt = rec.dt
    if columns["t"].scale == 1.0 and dt > SLOW_SAMPLING_S:
        notes.append(f"the samples are {dt:g} s apart: if the time column is not in seconds, "
                     "give its unit in the header (e.g. 't_ms' or 'time [ms]')")
    rec.notes = notes + rec.notes
    return rec


def _read_table_arrow(path: Path, layout: _Layout, columns: dict) -> dict | None:
    """The wanted columns as float arrays, or None if pyarrow refuses the file."""
    import pyarrow as pa
    import pyarrow.csv as pacsv
    names = [f"c{i}" for i in range(len(layout.first))]
    wanted = {c: names[col.index] for c, col in columns.items()}
    try:
        table = pacsv.read_csv(
            path, read_options=pacsv.ReadOptions(column_names=names,
                                                 skip_rows=layout.skip,
                                                 encoding=layout.encoding.replace("-sig", "")),
            parse_options=pacsv.ParseOptions(delimiter=layout.delimiter),
            convert_options=pacsv.ConvertOptions(
                include_columns=list(wanted.values()),
                column_types={name: pa.float64() for name in wanted.values()},
                decimal_point=layout.decimal,
                null_values=["", "nan", "NaN", "NAN", "na", "NA", "null", "NULL"],
                strings_can_be_null=True))
    except Exception:   # pyarrow refused it: the line reader says exactly where and why
        return None
    if table.num_rows == 0:
        raise DataError(f"{path}: no data rows" + (" after the header" if layout.has_header else ""))
    return {c: table.column(name).to_numpy(zero_copy_only=False).astype(float)
            for c, name in wanted.items()}


def _read_table_lines(path: Path, layout: _Layout, columns: dict) -> dict:
    order = list(columns)
    rows = []
    try:
        with _open_text(path, layout.encoding) as fh:
            for lineno, line in enumerate(fh, start=1):
                if lineno <= layout.skip:
                    continue
                if line.lstrip().startswith("#"):
                    continue
                row = _split(line.rstrip("\r\n"), layout.delimiter)
                if not row or all(not c.strip() for c in row):
                    continue
                try:
                    rows.append([_num(row[columns[c].index], layout.decimal)
                                 if columns[c].index < len(row) else math.nan for c in order])
                except ValueError as exc:
                    raise DataError(f"{path}:{lineno}: {exc}") from None
    except (OSError, UnicodeDecodeError, EOFError) as exc:
        raise DataError(f"cannot read {path}: {exc}") from None
    if not rows:
        raise DataError(f"{path}: no data rows" + (" after the header" if layout.has_header else ""))
    a = np.array(rows, float)
    return {c: a[:, k] for k, c in enumerate(order)}


def _num(text: str, decimal: str = ".") -> float:
    text = text.strip()
    if text == "" or text.lower() in ("nan", "na", "null"):
        return math.nan
    try:
        return float(text.replace(",", ".") if decimal == "," else text)
    except ValueError:
        raise ValueError(f"{text!r} is not a number") from None


def write_csv(record: Record, path: str | Path) -> None:
    with Path(path).open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["t", "u", "y", "r"])
        for row in zip(record.t, record.u, record.y, record.r):
            w.writerow([repr(float(v)) for v in row])

