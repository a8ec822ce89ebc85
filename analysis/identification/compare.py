"""Compare a model with measurements: fit it (or take it as given), evaluate the windowed
free-run error, print it as a short table and (with :mod:`analysis.reports.plots`) draw it.

This is the library behind ``stand fit``, ``stand compare`` and ``stand report``; everything the
commands print is also available here as data.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from plant import PlantModel, load_model_file
from plant.params import ModelError

from ..records.record import Record
from .fit import FitResult, fit_model
from .metrics import Evaluation, evaluate
from .windows import WINDOW_S


def resolve_model(text: str | PlantModel, complete: bool = False) -> tuple[PlantModel, str | None]:
    """A model from ``base+reversal+deadzone`` or from a TOML model file (``complete``: the file
    must give every parameter). Returns the model and the file it came from (None for a spec)."""
    if isinstance(text, PlantModel):
        return text, None
    text = str(text).strip()
    path = Path(text)
    if text.lower().endswith(".toml") or path.is_file():
        if not path.is_file():
            raise ModelError(f"model file {path} does not exist (or give a spec like base+reversal)")
        return load_model_file(path, complete=complete), str(path)
    return PlantModel.from_spec(text), None


@dataclass
class Comparison:
    """A model confronted with a data set."""

    model: PlantModel
    evaluation: Evaluation
    fit: FitResult | None            #: None when the model was taken as given
    source: str                      #: the spec or model file it came from

    def metrics(self) -> dict[str, Any]:
        return self.evaluation.summary()

    def to_dict(self, full: bool = False) -> dict[str, Any]:
        out: dict[str, Any] = {"model": self.model.spec, "params": self.model.params(),
                               "metrics": self.metrics(), "source": self.source,
                               "fitted": self.fit is not None}
        if self.fit is not None:
            out["intervals"] = {k: e.to_dict() for k, e in self.fit.estimates.items()}
            out["fit"] = {"objective_rmse": self.fit.objective_rmse, "nfev": self.fit.nfev,
                          "success": self.fit.success, "message": self.fit.message,
                          "warnings": self.fit.warnings}
        if full:
            ev = self.evaluation.to_dict()
            out["regimes"] = ev["regimes"]
            out["windows"] = ev["windows"]
            out["worst_windows"] = ev["worst_windows"]
            out["whiteness"] = ev["whiteness"]
            out["input_correlation"] = ev["input_correlation"]
        return out


def compare(records: Sequence[Record], model: str | PlantModel, window_s: float = WINDOW_S,
            fit: bool = True) -> Comparison:
    """Fit ``model`` to ``records`` (unless ``fit=False``: its values as given) and evaluate it."""
    m, path = resolve_model(model)
    result = fit_model(records, m, window_s=window_s) if fit else None
    final = result.model if result is not None else m
    ev = evaluate(final, records, window_s)
    return Comparison(final, ev, result, path or m.spec)


# ------------------------------------------------------------------------------------------
# text
# ------------------------------------------------------------------------------------------
def _fmt(v: float, digits: int = 4) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "inf" if isinstance(v, float) and math.isinf(v) else "n/a"
    return f"{v:.{digits}g}"


def interval_label(estimate) -> str:
    """What to print beside a parameter: its 95 % interval, or why there is none."""
    if estimate is None:
        return "as given"
    if estimate.fixed:
        return "fixed"
    if estimate.at_bound:
        return "at its bound"
    if not estimate.identifiable:
        return "not identifiable"
    return interval_text(estimate.value, estimate.low, estimate.high)


def interval_text(value: float, low: float, high: float) -> str:
    """``[low, high]`` with enough digits to tell the ends from the value."""
    if not (math.isfinite(low) and math.isfinite(high)):
        return f"[{_fmt(low)}, {_fmt(high)}]"
    width = abs(high - low)
    scale = max(abs(value), abs(low), abs(high), 1e-300)
    digits = 4 if width == 0 else int(min(12, max(4, math.ceil(math.log10(scale / width)) + 2)))
    return f"[{low:.{digits}g}, {high:.{digits}g}]"


def params_table(c: Comparison) -> str:
    lines = [f"{'parameter':24s} {'value':>12s}  {'95 % interval':>27s}  unit"]
    specs = dict(c.model.param_specs())
    for name, value in c.model.params().items():
        unit = specs[name].unit
        ci = interval_label(c.fit.estimates.get(name) if c.fit is not None else None)
        lines.append(f"{name:24s} {_fmt(value, 6):>12s}  {ci:>27s}  {unit}")
    return "\n".join(lines)


def metrics_table(c: Comparison, worst: int = 3) -> str:
    ev = c.evaluation
    lines = [
        f"windowed free-run error ({ev.window_s:g} s windows from the measured force, "
        f"{len(ev.windows)} windows, {ev.n} samples)",
        f"  RMSE {ev.rmse:.4g} kgf   fit {ev.fit_percent:.2f} %   noise floor {ev.noise_floor:.3g} kgf "
        f"(σ = {ev.noise_sigma:.3g} kgf)",
        f"  with the window starts re-estimated: RMSE {ev.rmse_adjusted:.4g} kgf = "
        f"{ev.excess_ratio:.2f}× its floor {ev.adjusted_floor:.3g} kgf (1.00 = as good as the noise allows)",
        "",
        f"  {'regime':34s} {'time':>6s} {'RMSE':>9s} {'SSE share':>9s} {'slope err':>11s}",
    ]
    group = None
    for r in ev.regimes:
        if r.group != group:
            lines.append(f"  [{r.group}]")
            group = r.group
        rel = f"{100 * r.rate_bias_rel:+.1f} %" if math.isfinite(r.rate_bias_rel) and abs(r.rate_bias_rel) < 10 else \
            f"{r.rate_bias:+.3g}/s"
        lines.append(f"  {r.name:34s} {100 * r.time_share:5.1f}% {r.rmse:9.4g} {100 * r.sse_share:8.1f}% {rel:>11s}")
    lines.append("")
    lines.append("  worst windows: " + "; ".join(
        f"rec {w.record} {w.t_start:.1f}–{w.t_end:.1f} s: {w.rmse:.3g} kgf ({w.regime})"
        for w in ev.worst_windows(worst)))
    wt, ic = ev.whiteness, ev.input_correlation
    lines.append(f"  residual whiteness: {'white' if wt.white else 'NOT white'} (Ljung–Box p = {wt.p_value:.2g}, "
                 f"{100 * wt.outside_share:.0f} % of lags 1..{wt.lags[-1]} outside ±{wt.band:.3g})")
    lines.append(f"  input–residual correlation: {'none' if ic.white else 'PRESENT'} (p = {ic.p_value:.2g}, "
                 f"max |ρ| {ic.max_abs:.3g} vs band ±{ic.band:.3g})")
    return "\n".join(lines)


def jsonable(obj: Any) -> Any:
    """Recursively turn numpy scalars/arrays into Python, NaN into null and ±inf into strings,
    so that ``json.dumps`` writes strict JSON."""
    if isinstance(obj, dict):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return jsonable(obj.tolist())
    if isinstance(obj, (np.bool_,)):
        return bool(obj)
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        v = float(obj)
        if math.isnan(v):
            return None
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return v
    return obj
