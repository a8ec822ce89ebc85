"""Analysis: the paper's estimators, model fit, comparison and diagnosis.

Inputs come in through :mod:`analysis.data` (CSV, run directories, bus captures) as
:class:`~analysis.data.Record`; the plant model is :mod:`plant` (the same code the emulator runs).
"""
