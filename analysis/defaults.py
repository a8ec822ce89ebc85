"""Defaults the command line shows in its help, kept apart from the numerics that use them (so
``stand X --help`` does not import numpy and scipy)."""

#: length of the free-run simulation windows, s
WINDOW_S = 2.0
#: effects ``stand diagnose --stepwise`` adds at most
MAX_EFFECTS = 5
#: suffixes read as a table of samples, each optionally gzipped (analysis.records.tables)
TABLE_SUFFIXES = (".csv", ".tsv", ".txt", ".dat")
#: the paper's experiments the estimators know
EXPERIMENT_NAMES = ("meander", "pfeedback", "relay")
#: the verdicts of ``stand diagnose`` (analysis.diagnosis.verdict) and what each says, as its
#: help gives them
VERDICTS = {
    "adequate": "the error is within the noise",
    "missing_effect": "the best effect, named",
    "varies_between_records": "the stand changed between the records: a gain or a trend of "
                              "each record's own explains the error better than any effect",
    "unexplained": "structure no effect removes, described",
}
