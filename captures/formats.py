"""The capture formats by file suffix: which are read by our vectorized readers and which
through python-can's log readers (kept apart from the readers so a command's help can name
them without importing numpy and the CAN stack)."""

VECTORIZED = {".log": "candump", ".blf": "blf"}
VIA_PYTHON_CAN = {".asc": "asc", ".trc": "trc", ".csv": "csv", ".db": "sqlite", ".mf4": "mf4"}
SUFFIXES = tuple(VECTORIZED) + tuple(VIA_PYTHON_CAN)
