"""The layout is the architecture: a layer imports only the layers below it (docs/architecture.md).
Every import is read, function-local ones too, so a cycle cannot hide behind a late import."""
from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

#: packages from the bottom up; a package may import its own modules and any lower level's
LEVELS = [
    {"core"},
    {"standbus"},
    {"dbc"},
    {"plant"},
    {"plant_emulator", "loading"},
    {"gateway"},
    {"captures"},
    {"analysis"},
    {"stand"},
    {"benchmarks"},
]
LEVEL = {pkg: i for i, level in enumerate(LEVELS) for pkg in level}


def imports(path: Path) -> list[tuple[int, str]]:
    """(line, top-level package) of every absolute import in a module, at any depth."""
    out = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            out += [(node.lineno, a.name.split(".")[0]) for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            out.append((node.lineno, node.module.split(".")[0]))
    return out


def test_no_layer_imports_a_layer_above_it_or_beside_it():
    wrong = []
    for pkg, level in LEVEL.items():
        for path in sorted((ROOT / pkg).rglob("*.py")):
            for line, target in imports(path):
                if target in LEVEL and target != pkg and LEVEL[target] >= level:
                    wrong.append(f"{path.relative_to(ROOT)}:{line}: {pkg} (level {level}) imports "
                                 f"{target} (level {LEVEL[target]})")
    assert not wrong, "layer violations:\n" + "\n".join(wrong)


def test_every_package_has_a_level():
    packages = {p.parent.name for p in ROOT.glob("*/__init__.py")} - {"tests"}
    assert packages <= set(LEVEL), f"give these a level in LEVELS: {sorted(packages - set(LEVEL))}"
