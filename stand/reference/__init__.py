"""The reference pages (``docs/reference/``), generated from the code: the command line from its
parsers, and every file format the commands read and write, in one place each, from the
loaders' constants, dataclasses and docstrings (with the meanings the code does not hold
written beside them in this package). ``python -m stand.reference docs/reference`` writes them;
``--check`` says which differ from what the code would write now (tests/test_reference.py).

Each page is a pure function of the code: no terminal width, no clock, no host, no installed
plug-in enters it, so two checkouts of one commit write the same bytes, and a branch that adds
an option regenerates a page that merges by regenerating again.
"""
from __future__ import annotations

from pathlib import Path
from typing import Callable

from . import markdown as md


def _pages() -> dict[str, tuple[str, Callable[[], str]]]:
    """file name -> (what it documents, its generator), in the index's order."""
    from . import (cli_page, controller_file, devices_file, endurance_file, model_files, outputs,
                   rig_file, run_dir, tables_page)
    return {
        "cli.md": ("every command and option of `stand`, with its default", cli_page.cli_page),
        "run.md": ("the run directory: `run.json`, the signals, the captures", run_dir.page),
        "tables.md": ("tables of samples (CSV) the analysis reads: names, units, rules", tables_page.page),
        "model-toml.md": ("model files, plant files (the emulator's) and rig model files", model_files.page),
        "controller-toml.md": ("controller files, a stand's and a rig's (`stand design`)",
                               controller_file.page),
        "rig-toml.md": ("the rig file: buses, channels, structure", rig_file.page),
        "devices-toml.md": ("a device file: a maker's valve drive and amplifier, their EDS and roles",
                            devices_file.page),
        "test-toml.md": ("an endurance test's file", endurance_file.page),
        "load-json.md": ("`stand load --json`: the loading summary (`hydrostand-load/1`)", outputs.load_page),
        "test-status-json.md": ("`stand test status --json`: an endurance test's status", outputs.status_page),
    }


def index_page() -> str:
    rows = [[f"[{name}]({name})", what] for name, (what, _) in _pages().items()]
    intro = ("What every command takes and every file holds, generated from the code (`python -m "
             "stand.reference docs/reference`; the suite fails when a page differs from what the "
             "code would write). How to use them: the [README](../../README.md) and the how-to pages "
             "it links to.")
    return md.page("Reference", intro, md.table(["page", "what it documents"], rows))


def pages() -> dict[str, str]:
    """Every page's file name and text."""
    out = {"README.md": index_page()}
    out.update({name: make() for name, (_, make) in _pages().items()})
    return out


def write(directory: str | Path) -> list[Path]:
    """Write every page into ``directory``; returns the files whose text changed."""
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    changed = []
    for name, text in pages().items():
        path = directory / name
        if not path.exists() or path.read_text(encoding="utf-8") != text:
            path.write_text(text, encoding="utf-8")
            changed.append(path)
    return changed


def stale(directory: str | Path) -> list[str]:
    """The pages of ``directory`` that differ from what the code writes now (missing ones too),
    and generated pages there the code no longer writes."""
    directory = Path(directory)
    expected = pages()
    out = [name for name, text in expected.items()
           if not (directory / name).exists() or (directory / name).read_text(encoding="utf-8") != text]
    out += sorted(p.name for p in directory.glob("*.md") if p.name not in expected
                  and p.read_text(encoding="utf-8").startswith(md.GENERATED))
    return out
