"""Data as users bring it, made records.

- :mod:`.record`: :class:`~.record.Record` (uniformly sampled t, u, y, r and where they came
  from), :func:`~.record.make_record` (validation, resampling, glitches, limit holds),
  :func:`~.record.split_at_gaps`;
- :mod:`.tables`: tables of samples read (encoding, delimiter, decimal mark, header) and written;
- :mod:`.columns`: which column is which signal, in which unit;
- :mod:`.glitches`: one to three force samples far off the trend;
- :mod:`.limits`: stretches held at a hydraulic limit;
- :mod:`.load`: runs, tables and bus captures alike (:func:`~.load.load`, :func:`~.load.load_all`);
- :mod:`.synthetic`: known-answer records from the plant model.

Nothing is imported here: ``import analysis.records.columns`` stays light.
"""
