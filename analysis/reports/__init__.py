"""What the analysis shows: figures, the HTML report of a model's versions, the campaign report.

- :mod:`.plots`: measured vs model, the error per regime, residual tests, candidates;
- :mod:`.history`: a model history per data set (``history.json``) and its self-contained HTML
  report (``report.html``);
- :mod:`.campaign`: the paper's estimators over a campaign's runs: tables and figures.

Nothing is imported here (matplotlib is imported when a figure is drawn).
"""
