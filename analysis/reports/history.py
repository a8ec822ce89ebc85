"""Watch the error fall: a model history per data set and a self-contained HTML report.

``write_report(records, model, out_dir)`` fits (or takes as given) one model version, appends it
to ``out_dir/history.json`` (the history of *this* data set: its fingerprint is checked), and
writes ``out_dir/report.html``: the error of every version so far — falling as effects are added —
and, for the latest version, its parameters with intervals, the error per regime and window, the
residual tests and the plots. Images are embedded (base64 PNG) and the page has no external
reference, so it opens anywhere without a network.

Typical loop::

    stand report data.csv --model base                  # v1
    stand diagnose data.csv                             # -> missing effect: reversal
    stand report data.csv --model base+reversal         # v2, error falls
    stand fit data.csv --model base+reversal --save m.toml; edit m.toml; stand report data.csv --model m.toml
"""
from __future__ import annotations

import base64
import datetime as dt
import hashlib
import html
import io
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from gateway.errors import DataError
from plant import PlantModel

from ..identification.compare import Comparison, compare, interval_label, jsonable
from ..identification.windows import WINDOW_S
from ..records.record import Record
from . import plots

HISTORY_FILE = "history.json"
REPORT_FILE = "report.html"


def dataset_fingerprint(records: Sequence[Record]) -> dict[str, Any]:
    """Identity of a data set: a hash of its samples, plus what a person recognizes it by."""
    h = hashlib.sha1()
    for r in records:
        for a in (r.t, r.u, r.y):
            h.update(np.ascontiguousarray(a, dtype=np.float64).tobytes())
    return {"id": h.hexdigest()[:16], "sources": [str(r.source) for r in records],
            "records": len(records), "samples": int(sum(len(r) for r in records)),
            "duration_s": float(sum(r.duration_s for r in records)),
            "dt_s": sorted({round(r.dt, 9) for r in records})}


def load_history(out_dir: str | Path) -> dict[str, Any] | None:
    path = Path(out_dir) / HISTORY_FILE
    if not path.exists():
        return None
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise DataError(f"{path} is not a readable history ({exc}); remove it or use another --out") from None


def _same_version(a: dict, model: PlantModel, window_s: float) -> bool:
    if a.get("model") != model.spec or abs(a.get("window_s", WINDOW_S) - window_s) > 1e-12:
        return False
    p = a.get("params", {})
    return all(k in p and math.isclose(p[k], v, rel_tol=1e-9, abs_tol=1e-12)
               for k, v in model.params().items())


def record_version(history: dict[str, Any], c: Comparison, source: str) -> dict[str, Any]:
    """Append the comparison as a new version (or refresh the latest if it is the same model
    with the same values). Returns the version entry."""
    versions = history.setdefault("versions", [])
    entry = {
        "version": len(versions) + 1,
        "time": dt.datetime.now().isoformat(timespec="seconds"),
        "model": c.model.spec, "source": source, "fitted": c.fit is not None,
        "window_s": c.evaluation.window_s, "n_params": len(c.model.params()),
        "params": c.model.params(), "metrics": c.metrics(),
    }
    if versions and _same_version(versions[-1], c.model, c.evaluation.window_s):
        entry["version"] = versions[-1]["version"]
        versions[-1] = entry
    else:
        versions.append(entry)
    return entry


@dataclass
class ReportResult:
    path: Path                 #: the HTML page
    history_path: Path
    version: dict[str, Any]
    history: dict[str, Any]
    comparison: Comparison


def write_report(records: Sequence[Record], model: str | PlantModel, out_dir: str | Path,
                 fit: bool = True, window_s: float = WINDOW_S, new_history: bool = False,
                 diagnosis: Any = None, title: str | None = None) -> ReportResult:
    """Add one model version to the data set's history and rewrite the HTML report."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    fp = dataset_fingerprint(records)
    history = None if new_history else load_history(out)
    if history is not None and history.get("dataset", {}).get("id") != fp["id"]:
        old = history.get("dataset", {})
        raise DataError(f"{out} holds the model history of another data set "
                        f"({', '.join(old.get('sources', [])) or 'unknown'}); give another --out, "
                        "or --new-history to start this directory over")
    if history is None:
        history = {"dataset": fp, "versions": []}
    c = compare(records, model, window_s=window_s, fit=fit)
    source = str(model) if not isinstance(model, PlantModel) else model.spec
    entry = record_version(history, c, source)
    hist_path = out / HISTORY_FILE
    hist_path.write_text(json.dumps(jsonable(history), indent=2, allow_nan=False))
    page = render_html(history, c, diagnosis=diagnosis, title=title)
    path = out / REPORT_FILE
    path.write_text(page, encoding="utf-8")
    return ReportResult(path, hist_path, entry, history, c)


# ------------------------------------------------------------------------------------------
# HTML
# ------------------------------------------------------------------------------------------
CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Roboto,sans-serif;margin:24px auto;max-width:1150px;
color:#222;line-height:1.4}h1{font-size:22px}h2{font-size:17px;margin-top:28px;border-bottom:1px solid #ddd}
table{border-collapse:collapse;font-size:13px;margin:8px 0}td,th{padding:3px 9px;border-bottom:1px solid #eee;
text-align:right}th{background:#f6f6f6}td.l,th.l{text-align:left}tr.latest{background:#fff4e5}
img{max-width:100%;border:1px solid #eee;margin:6px 0}.muted{color:#777;font-size:12px}
.verdict{font-weight:bold;padding:2px 8px;border-radius:4px;background:#eef}
ul{margin:4px 0 4px 18px;padding:0}code{background:#f4f4f4;padding:0 3px}
"""


def _img(fig_writer, *args) -> str:
    """Render a plot to PNG in memory and return an <img> with it embedded."""
    buf = io.BytesIO()
    fig_writer(*args, buf)
    data = base64.b64encode(buf.getvalue()).decode("ascii")
    return f'<img alt="plot" src="data:image/png;base64,{data}">'


def _e(x: Any) -> str:
    return html.escape(str(x))


def _num(v: Any, digits: int = 4) -> str:
    if v is None:
        return "n/a"
    if isinstance(v, (int, float)) and not math.isfinite(v):
        return "inf" if v > 0 else "-inf" if v < 0 else "n/a"
    return f"{v:.{digits}g}"


def render_html(history: dict[str, Any], c: Comparison, diagnosis: Any = None,
                title: str | None = None) -> str:
    ds = history["dataset"]
    versions = history["versions"]
    ev = c.evaluation
    name = title or ", ".join(Path(s).name for s in ds["sources"])
    parts = [f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>{_e(name)} — model history"
             f"</title><style>{CSS}</style></head><body>",
             f"<h1>Model history: {_e(name)}</h1>",
             f"<p class='muted'>data set {_e(ds['id'])}: {ds['records']} record(s), "
             f"{ds['samples']:,} samples, {ds['duration_s']:.1f} s, sample time "
             f"{', '.join(f'{d * 1e3:g} ms' for d in ds['dt_s'])}. Error = free-run simulation over "
             f"{ev.window_s:g} s windows, each started from the measured force. Generated "
             f"{_e(dt.datetime.now().isoformat(timespec='seconds'))} by <code>stand report</code>.</p>"]
    # -- history -------------------------------------------------------------------------------
    parts.append("<h2>Error of each model version</h2>")
    parts.append(_img(lambda v, f: plots.plot_history(v, f), versions))
    rows = ["<table><tr><th>version</th><th class='l'>model</th><th class='l'>from</th>"
            "<th>parameters</th><th>RMSE, kgf</th><th>change</th><th>fit, %</th>"
            "<th>× noise floor</th><th class='l'>when</th></tr>"]
    prev = None
    for v in versions:
        m = v["metrics"]
        change = "" if prev is None else f"{100 * (m['rmse'] / prev - 1):+.1f} %"
        cls = " class='latest'" if v is versions[-1] else ""
        rows.append(f"<tr{cls}><td>v{v['version']}</td><td class='l'><code>{_e(v['model'])}</code></td>"
                    f"<td class='l'>{_e(Path(v['source']).name)}{'' if v['fitted'] else ' (as given)'}</td>"
                    f"<td>{v['n_params']}</td><td>{_num(m['rmse'])}</td><td>{change}</td>"
                    f"<td>{_num(m['fit_percent'], 5)}</td><td>{_num(m.get('excess_ratio'), 3)}</td>"
                    f"<td class='l'>{_e(v['time'])}</td></tr>")
        prev = m["rmse"]
    rows.append("</table>")
    parts.append("".join(rows))
    # -- latest version ---------------------------------------------------------------------------
    parts.append(f"<h2>Latest: v{versions[-1]['version']} <code>{_e(c.model.spec)}</code></h2>")
    parts.append(f"<p>RMSE <b>{ev.rmse:.4g} kgf</b>, fit <b>{ev.fit_percent:.2f} %</b>, noise floor "
                 f"{ev.noise_floor:.3g} kgf (σ = {ev.noise_sigma:.3g} kgf). With the window starts "
                 f"re-estimated (the fit's objective) the error is <b>{ev.excess_ratio:.2f}×</b> what "
                 f"a perfect model would show.</p>")
    prow = ["<table><tr><th class='l'>parameter</th><th>value</th><th>95 % interval</th>"
            "<th class='l'>unit</th></tr>"]
    specs = dict(c.model.param_specs())
    for k, val in c.model.params().items():
        ci = interval_label(c.fit.estimates.get(k) if c.fit is not None else None)
        prow.append(f"<tr><td class='l'>{_e(k)}</td><td>{_num(val, 6)}</td><td>{_e(ci)}</td>"
                    f"<td class='l'>{_e(specs[k].unit)}</td></tr>")
    prow.append("</table>")
    parts.append("".join(prow))
    if c.fit is not None and c.fit.warnings:
        parts.append("<ul>" + "".join(f"<li class='muted'>{_e(w)}</li>" for w in c.fit.warnings) + "</ul>")
    parts.append("<h3>Measurement and model</h3>")
    parts.append(_img(lambda e, f: plots.plot_overlay(e, f), ev))
    parts.append("<h3>Where the error is</h3>")
    rrow = ["<table><tr><th class='l'>regime</th><th>time</th><th>RMSE, kgf</th><th>share of error</th>"
            "<th>slope error along the motion</th></tr>"]
    for r in ev.regimes:
        rel = f"{100 * r.rate_bias_rel:+.1f} %" if math.isfinite(r.rate_bias_rel) and abs(r.rate_bias_rel) < 10 else "n/a"
        hot = " style='background:#fff0e0'" if r.sse_share > 1.5 * r.time_share else ""
        rrow.append(f"<tr{hot}><td class='l'>{_e(r.group)}: {_e(r.name)}</td><td>{100 * r.time_share:.1f} %</td>"
                    f"<td>{_num(r.rmse)}</td><td>{100 * r.sse_share:.1f} %</td><td>{rel}</td></tr>")
    rrow.append("</table>")
    parts.append("".join(rrow))
    parts.append(_img(lambda e, f: plots.plot_regimes(e, f), ev))
    worst = ev.worst_windows(5)
    parts.append("<p>Worst windows: " + "; ".join(
        f"record {w.record}, {w.t_start:.1f}–{w.t_end:.1f} s: {w.rmse:.3g} kgf ({_e(w.regime)})"
        for w in worst) + "</p>")
    parts.append("<h3>Residual tests</h3>")
    wt, ic = ev.whiteness, ev.input_correlation
    parts.append(f"<p>Whiteness: {'white' if wt.white else '<b>not white</b>'} (Ljung–Box p = {wt.p_value:.2g}); "
                 f"input–residual correlation: {'none' if ic.white else '<b>present</b>'} "
                 f"(p = {ic.p_value:.2g}); bands ±1.96/√N = ±{wt.band:.3g}.</p>")
    parts.append(_img(lambda e, f: plots.plot_correlations(e, f), ev))
    if diagnosis is not None:
        parts.append(_diagnosis_html(diagnosis))
    parts.append("</body></html>")
    return "\n".join(parts)


def _diagnosis_html(d: Any) -> str:
    out = [f"<h2>What <code>{_e(d.model)}</code> still misses</h2>",
           f"<p><span class='verdict'>{_e(d.verdict)}</span> {_e(d.summary)}</p>",
           "<table><tr><th class='l'>model</th><th>RMSE, kgf</th><th>change</th><th>earns its parameters</th></tr>",
           f"<tr><td class='l'><code>{_e(d.base_fit.model.spec)}</code></td><td>{_num(d.base_eval.rmse)}</td><td></td><td></td></tr>"]
    for c in d.candidates:
        out.append(f"<tr><td class='l'>+{_e(c.effect)}</td><td>{_num(c.rmse)}</td>"
                   f"<td>{-100 * c.rmse_reduction:+.1f} %</td><td>{'yes' if c.earns else 'no'}</td></tr>")
    out.append("</table><ul>")
    out += [f"<li>{_e(o)}</li>" for o in d.observations]
    out += [f"<li><b>cannot tell</b>: {_e(a.text())}</li>" for a in d.ambiguities]
    out.append("</ul>")
    return "".join(out)
