"""Defaults the command line shows in its help, kept apart from the numerics that use them (so
``stand X --help`` does not import numpy and scipy)."""

#: length of the free-run simulation windows, s
WINDOW_S = 2.0
#: effects ``stand diagnose --stepwise`` adds at most
MAX_EFFECTS = 5
#: the paper's experiments the estimators know
EXPERIMENT_NAMES = ("meander", "pfeedback", "relay")
