"""``docs/reference/tables.md``: the tables of samples the analysis reads
(:mod:`analysis.records.tables`, :mod:`analysis.records.columns`, :mod:`analysis.records.record`).
The names and units every signal is known by, the file types, delimiters, encodings and the
limits are the code's constants; the rules around them are written here, and
``tests/test_reference.py`` reads the shipped sample tables by them."""
from __future__ import annotations

from . import markdown as md


def _signals() -> str:
    from analysis.records.columns import REQUIRED, SIGNALS
    rows = []
    for signal, (what, names, units) in SIGNALS.items():
        own = next(iter(units))
        shown = ", ".join(md.code(u) + ("" if f == 1.0 else f" (× {f:.6g})") for u, f in units.items())
        rows.append([md.code(signal), what + ("" if signal in REQUIRED else " (optional)"),
                     ", ".join(md.code(n) for n in names), md.code(own), shown])
    return md.table(["signal", "what", "column names (any case)", "its unit", "units read (× to its unit)"],
                    rows)


def page() -> str:
    from analysis.records.record import GAP_INTERVALS, JITTER_TOLERANCE
    from analysis.records.tables import _DELIMITERS, _LEGACY_ENCODINGS, SLOW_SAMPLING_S, TABLE_SUFFIXES
    from captures.formats import SUFFIXES
    delimiters = {",": "comma", ";": "semicolon", "\t": "tab"}
    intro = ("`stand fit`, `compare`, `diagnose`, `report` and `estimate` take tables of samples "
             "beside run directories and bus captures: a time column, the valve command, the "
             "force and, optionally, the force reference, in whatever names and units a logger "
             "wrote. What was converted or changed is said in a note on stderr; what cannot be "
             "read is an error naming the file, the line or the column. Two samples ship with the "
             "project: `examples/meander.csv` (English) and `examples/meander-logger.csv` (a "
             "Russian logger's `Время, мс;Управление, В;Усилие, кН` in Windows-1251 with decimal "
             "commas): [docs/analysis.md](../analysis.md) compares and diagnoses them.")
    files = [
        f"**File types**: {', '.join(md.code(s) for s in TABLE_SUFFIXES)}, each optionally gzipped "
        f"(`.csv.gz`). A `.csv` whose header is python-can's (`timestamp,arbitration_id,...`) is a "
        f"bus capture, as are {', '.join(md.code(s) for s in SUFFIXES if s != '.csv')} "
        "([captures](../captures.md)).",
        f"**Delimiter**: {', '.join(delimiters[d] for d in _DELIMITERS)}, or runs of blanks. The "
        "one that splits every one of the first lines into the same number of fields; where "
        "several do, the one whose header names the signals and whose fields are numbers, then the "
        "more frequent. A first line `sep=;` (Excel's) names it.",
        "**Decimal mark**: a point, or a comma where the delimiter is not one (`0,5;12,25`).",
        "**Encoding**: UTF-8 (with or without a byte-order mark); else, with a note, "
        + " or ".join(_LEGACY_ENCODINGS.values())
        + ", told apart by the runs of Cyrillic letters in the bytes.",
        "**Header**: the first line unless every field is a number; a leading `#` is taken off it "
        "(numpy's `# t,u,y`). A second line of units only (`s;kN`) is read as the names' units. "
        "Later lines starting with `#` are comments. Without a header, 3 or 4 columns are read as "
        "`t,u,y[,r]` in s, %, kgf (with a note).",
        "**Columns**: found by name, in any case, with the unit written after the name: "
        "`time [ms]`, `force (kN)`, `force_N`, `u/V`, `load in kN`, `Усилие, кгс`. Other columns "
        "are ignored. A signal in two columns, a missing `t`, `u` or `y`, or a unit not in the "
        "table below is an error that says which.",
        "**Values**: empty, `nan`, `NA`, `null` are missing; a row missing t, u or y is dropped "
        "(noted).",
    ]
    samples = [
        f"**Time**: rows a few samples out of order are sorted and repeated times dropped (noted). "
        f"Time that goes back by more than {GAP_INTERVALS} sample intervals (two runs in one file, "
        "a logger's clock reset) is an error: give each run a file.",
        f"**Sampling**: jitter over {100 * JITTER_TOLERANCE:g} % of the interval is resampled to a "
        f"uniform grid (noted); a gap of more than {GAP_INTERVALS} intervals splits the table into "
        "records of their own. Samples more than "
        f"{SLOW_SAMPLING_S:g} s apart in a time column without a unit get a note asking whether "
        "it is in seconds.",
        "**Force**: glitches (1-3 samples far off the trend) are replaced by the line between "
        "their neighbours, readings clipped at the dynamometer's range and holds at a hydraulic "
        "limit are noted ([docs/analysis.md](../analysis.md)).",
        "**Several files** given together are one data set, each on its own time base.",
    ]
    return md.page("Tables of samples (CSV)", intro, "## Reading a file",
                   "\n".join(f"* {s}" for s in files), "## The signals and their units", _signals(),
                   "## What is done to the samples", "\n".join(f"* {s}" for s in samples))
