"""Any plant model fitted to records, evaluated and compared.

- :mod:`.windows`: the data set cut into pieces and windows, and the windowed free-run
  simulation and residual on them;
- :mod:`.projection`: the base gain g and trend Δ solved by linear least squares (variable
  projection);
- :mod:`.starts`: start values (the data's summary, each effect's start grid, the delay search);
- :mod:`.fit`: :func:`~.fit.fit_model`, the least squares with confidence intervals;
- :mod:`.metrics`: :func:`~.metrics.evaluate`, the windowed error and where it lives;
- :mod:`.compare`: a model confronted with a data set, as tables.

Nothing is imported here: each module is imported when used.
"""
