"""The page of a loading test (``stand report LOAD_DIR``): the passes' figures, the tracking
figure and every channel's gain through the test, from what ``stand load`` wrote
(``report.json``, ``tracking.png``, ``pass-N/gain.json``). Self-contained HTML (images
embedded), no network."""
from __future__ import annotations

import base64
import html
import json
import math
from pathlib import Path

from core.errors import DataError

from .report import SCHEMA


def is_load_dir(path: str | Path) -> bool:
    """True for a directory ``stand load --out`` wrote."""
    f = Path(path) / "report.json"
    if not f.is_file():
        return False
    try:
        return json.loads(f.read_text()).get("schema") == SCHEMA
    except (OSError, ValueError):
        return False


def gain_blocks(load_dir: str | Path) -> dict[str | None, list[dict]]:
    """Every pass's gain blocks in test order, by channel (a one-channel stand's under None;
    empty when the test ran without the monitor)."""
    out: dict[str | None, list[dict]] = {}
    for p in sorted(Path(load_dir).glob("pass-*/gain.json"), key=lambda f: int(f.parent.name.split("-")[1])):
        blocks = json.loads(p.read_text()).get("blocks", [])
        for name, bs in (blocks.items() if isinstance(blocks, dict) else [(None, blocks)]):
            out.setdefault(name, []).extend(bs)
    return out


def plot_gain(blocks: list[dict], g_ref: float, fall_pct: float | None, rise_pct: float | None,
              path: str | Path, title: str = "") -> Path:
    """g through the test: each block's estimate with its 95 % interval at the block's middle,
    the model's g, the alarm thresholds, the feedforward's g, pass boundaries and the alarm."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    est = [b for b in blocks if b.get("g") is not None]
    fig, ax = plt.subplots(figsize=(11, 4.5))
    if est:
        t = [(b["start_s"] + b["end_s"]) / 2 for b in est]
        g = [b["g"] for b in est]
        err = [[b["g"] - b["low"] for b in est], [b["high"] - b["g"] for b in est]]
        ax.errorbar(t, g, yerr=err, fmt="o", ms=3, lw=0.8, capsize=2, label="estimate, 95 % interval")
        ax.step([b["start_s"] for b in blocks] + [blocks[-1]["end_s"]],
                [b.get("follow_g") or g_ref for b in blocks] + [blocks[-1].get("follow_g") or g_ref],
                where="post", lw=0.8, color="0.5", label="the feedforward's g (from the next block)")
    ax.axhline(g_ref, color="k", lw=1, label=f"model's g {g_ref:.1f}")
    if fall_pct:
        ax.axhline(g_ref * (1 - fall_pct / 100), color="tab:red", ls="--", lw=0.8, label=f"fall -{fall_pct:g} %")
    if rise_pct:
        ax.axhline(g_ref * (1 + rise_pct / 100), color="tab:orange", ls="--", lw=0.8, label=f"rise +{rise_pct:g} %")
    starts = {}
    for b in blocks:
        starts.setdefault(b["pass_index"], b["start_s"])
    for i, s in starts.items():
        if i > 1:
            ax.axvline(s, color="0.8", lw=0.8)
    for b in blocks:
        if b.get("alarm"):
            ax.axvline(b["end_s"], color="tab:red", lw=1.5)
            ax.annotate(f"alarm: {b['alarm']}", (b["end_s"], b["g"]), xytext=(5, 10),
                        textcoords="offset points", color="tab:red")
    ax.set_xlabel("stand time of the test, s (passes one after the other)")
    ax.set_ylabel("g, kgf/(%·s)")
    ax.set_title(title or "the stand's g through the test")
    ax.legend(loc="best", fontsize=8)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def _img(path: Path) -> str:
    data = base64.b64encode(path.read_bytes()).decode("ascii")
    return f'<img alt="{html.escape(path.name)}" src="data:image/png;base64,{data}">'


def _num(v, fmt: str = "{:.3f}") -> str:
    return "" if v is None or (isinstance(v, float) and math.isnan(v)) else fmt.format(v)


def write_load_page(load_dir: str | Path, title: str | None = None) -> Path:
    """``LOAD_DIR/report.html`` (and ``gain.png`` when the monitor ran); returns the page."""
    d = Path(load_dir)
    if not is_load_dir(d):
        raise DataError(f"{d}: not a directory written by stand load (no report.json of {SCHEMA})")
    summary = json.loads((d / "report.json").read_text())
    e = html.escape
    name = title or d.name
    parts = [f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>{e(name)}: loading</title>"
             "<style>body{font-family:sans-serif;margin:2em}table{border-collapse:collapse}"
             "td,th{border:1px solid #bbb;padding:3px 8px;text-align:right}img{max-width:100%}</style>"
             f"</head><body><h1>{e(name)}: loading test</h1>",
             f"<p>ended: {e(str(summary.get('end_reason')))}"
             + (f" ({e(summary['end_message'])})" if summary.get("end_message") else "") + "</p>",
             "<table><tr><th>pass</th><th>programme s</th><th>minimum s</th><th>× minimum</th>"
             "<th>pacing s</th><th>p95 %</th><th>max %</th><th>RMS %</th><th>extra cycles</th></tr>"]
    for i, p in enumerate(summary.get("passes", []), start=1):
        pv = p.get("peak_valley_error_pct", {})
        parts.append(f"<tr><td>{i}</td><td>{_num(p.get('programme_time_s'), '{:.1f}')}</td>"
                     f"<td>{_num(p.get('minimum_time_s'), '{:.1f}')}</td>"
                     f"<td>{_num(p.get('time_over_minimum'), '{:.2f}')}</td>"
                     f"<td>{_num(p.get('pacing_s'), '{:.2f}')}</td><td>{_num(pv.get('p95'))}</td>"
                     f"<td>{_num(pv.get('max'))}</td><td>{_num(p.get('rms_error_pct'))}</td>"
                     f"<td>{_num(p.get('extra_cycles'), '{:g}')}</td></tr>")
    parts.append("</table>")
    if summary.get("schedule"):
        s = summary["schedule"]
        parts.append(f"<p>schedule: {s['time_s']:.1f} s, {s['time_s'] / s['minimum_time_s']:.2f}× the "
                     f"valve-limited minimum, accuracy {s['accuracy_pct']:g} % "
                     f"({'converged' if summary.get('converged') else 'not converged'})</p>")
    if (d / "tracking.png").is_file():
        parts += ["<h2>Tracking, last pass</h2>", _img(d / "tracking.png")]
    gain = summary.get("gain")
    for name, blocks in gain_blocks(d).items():
        if not blocks or not gain:
            continue
        own = gain if name is None else gain["channels"][name]
        png = plot_gain(blocks, own["g_reference"], gain.get("fall_pct"), gain.get("rise_pct"),
                        d / ("gain.png" if name is None else f"gain-{name}.png"),
                        title="" if name is None else f"channel {name}: its gain through the test")
        heading = "The stand's g through the test" if name is None else f"Channel {e(name)}: its gain through the test"
        parts += [f"<h2>{heading}</h2>", _img(png),
                  f"<p>{own['blocks_estimated']} of {own['blocks_total']} blocks estimated; alarm: "
                  f"{e(str(own.get('alarm')))}"
                  + (f" — {e(own['alarm_message'])} (action {e(gain['action'])})" if own.get("alarm") else "")
                  + "</p>"]
    parts.append("</body></html>")
    out = d / "report.html"
    out.write_text("\n".join(parts))
    return out
