"""Analysis: the paper's estimators, model fit, comparison and diagnosis.

Subpackages by job, each importing only those below it (tests/test_layers.py):

- :mod:`analysis.records`: data as users bring it (tables, runs, captures) made
  :class:`~analysis.records.record.Record`;
- :mod:`analysis.estimators`: the paper's estimators (meander, P feedback, relay) and the
  dispatch that recognises the experiment;
- :mod:`analysis.identification`: any plant model fitted to records by least squares on the
  windowed free-run error (:func:`fit_model`), evaluated (:func:`evaluate`) and compared;
- :mod:`analysis.diagnosis`: what a model misses (:func:`diagnose`), built up one effect at a
  time (:func:`stepwise`), and what the data cannot tell apart;
- :mod:`analysis.reports`: figures, the HTML report of a model's versions and the campaign
  report.

:mod:`analysis.defaults` (the command line's defaults, no numerics) and :mod:`analysis.parallel`
(worker processes, one BLAS thread) sit below them all. The plant model is :mod:`plant` (the same
code the emulator runs). The public names below are imported on first use (:mod:`core.lazy`), so
``from analysis import load`` works and ``import analysis.defaults`` stays light.
"""
from __future__ import annotations

from core.lazy import lazy_exports

# name -> the module that defines it (relative to this package), imported on first use
_EXPORTS = {
    "Record": ".records.record",
    "make_record": ".records.record",
    "split_at_gaps": ".records.record",
    "read_csv": ".records.tables",
    "write_csv": ".records.tables",
    "load": ".records.load",
    "load_all": ".records.load",
    "load_capture": ".records.load",
    "read_run": ".records.load",
    "EstimateOptions": ".estimators.dispatch",
    "Estimate": ".estimators.dispatch",
    "detect_experiment": ".estimators.dispatch",
    "estimate_record": ".estimators.dispatch",
    "estimate_path": ".estimators.dispatch",
    "result_json": ".estimators.dispatch",
    "error_json": ".estimators.dispatch",
    "MeanderEstimate": ".estimators.meander",
    "estimate_meander": ".estimators.meander",
    "PFeedbackEstimate": ".estimators.pfeedback",
    "estimate_pfeedback": ".estimators.pfeedback",
    "RelayEstimate": ".estimators.relay",
    "estimate_relay": ".estimators.relay",
    "FitOptions": ".identification.fit",
    "FitResult": ".identification.fit",
    "ParamEstimate": ".identification.fit",
    "fit_model": ".identification.fit",
    "Evaluation": ".identification.metrics",
    "evaluate": ".identification.metrics",
    "Comparison": ".identification.compare",
    "compare": ".identification.compare",
    "resolve_model": ".identification.compare",
    "Candidate": ".diagnosis.candidates",
    "diagnosable_effects": ".diagnosis.candidates",
    "Diagnosis": ".diagnosis.verdict",
    "diagnose": ".diagnosis.verdict",
    "BetweenRecords": ".diagnosis.between_records",
    "between_records": ".diagnosis.between_records",
    "Stepwise": ".diagnosis.stepwise",
    "stepwise": ".diagnosis.stepwise",
    "write_report": ".reports.history",
    "load_history": ".reports.history",
    "report_campaign": ".reports.campaign",
}
__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
