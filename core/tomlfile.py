"""Reading a TOML file the user wrote, with one clear error for every way it can fail."""
from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

from .errors import ParameterError

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib


def read_toml(path: str | Path, error: type[Exception] = ParameterError) -> dict[str, Any]:
    """The parsed file; ``error`` (a :class:`~core.errors.StandError`) naming the file when it
    does not exist, cannot be read or is not valid TOML."""
    path = Path(path)
    try:
        with path.open("rb") as fh:
            return tomllib.load(fh)
    except FileNotFoundError:
        raise error(f"file {path} does not exist") from None
    except tomllib.TOMLDecodeError as exc:
        raise error(f"{path} is not valid TOML: {exc}") from None
    except OSError as exc:
        raise error(f"cannot read {path}: {exc}") from None
