"""The layout is the architecture: a layer imports only the layers below it (docs/architecture.md).
Every import is read, function-local ones too, so a cycle cannot hide behind a late import.
The tests keep a layout too: shared helpers in tests/support/, no test module imports another."""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

#: packages from the bottom up; a package may import its own modules and any lower level's
LEVELS = [
    {"core"},
    {"standbus"},
    {"dbc"},
    {"devices"},
    {"plant"},
    {"rig"},
    {"plant_emulator", "loading"},
    {"gateway"},
    {"captures"},
    {"analysis"},
    {"endurance"},
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


#: the parts of a package from the bottom up, the same rule inside it: a part imports its own
#: modules and those of the levels below; a package's __init__.py only names the public API
#: (imported lazily)
PART_LEVELS = {
    "analysis": [
        {"defaults", "parallel"},
        {"executors"},
        {"records"},
        {"estimators", "identification", "rig"},
        {"diagnosis"},
        {"reports"},
    ],
    # the effect contract at the bottom, the built-ins and the loader above it, the model above
    # them, then what loads a user's plug-ins (it checks them by simulating), the rig's coupled
    # channels, then the files (model files, a rig's among them, and emulator configurations)
    "plant": [
        {"params", "evidence"},
        {"signals", "start_grids", "sensor"},
        {"contract"},
        {"effects", "loader"},
        {"catalogue"},
        {"model"},
        {"plugins", "rig"},
        {"config", "skeleton"},
    ],
}


def part_of(package: str, path: Path) -> str:
    """The part of a package a module belongs to: its subpackage, or its own name at the top."""
    return path.relative_to(ROOT / package).parts[0].removesuffix(".py")


def part_imports(package: str, path: Path) -> list[tuple[int, str]]:
    """(line, part of ``package``) of every import of ``package`` in a module, relative or
    absolute, at any depth."""
    here = [package, *path.relative_to(ROOT / package).parent.parts]
    out = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            targets = [a.name.split(".") for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = (here[:len(here) - node.level + 1] if node.level else [])
            base += node.module.split(".") if node.module else []
            # "from . import plots", "from analysis import diagnose": the names may be modules
            targets = [base + [a.name] for a in node.names] if len(base) == 1 else [base]
        else:
            continue
        out += [(node.lineno, t[1]) for t in targets if t[0] == package and len(t) > 1]
    return out


def part_modules(package: str) -> list[Path]:
    return sorted(p for p in (ROOT / package).rglob("*.py") if p != ROOT / package / "__init__.py")


@pytest.mark.parametrize("package", sorted(PART_LEVELS))
def test_the_parts_of_a_package_import_only_the_levels_below_them(package):
    level = {part: i for i, parts in enumerate(PART_LEVELS[package]) for part in parts}
    wrong = []
    for path in part_modules(package):
        own = part_of(package, path)
        for line, target in part_imports(package, path):
            if target != own and level.get(target, -1) >= level[own]:
                wrong.append(f"{path.relative_to(ROOT)}:{line}: {package}.{own} (level "
                             f"{level[own]}) imports {package}.{target} (level {level[target]})")
    assert not wrong, f"layer violations inside {package}:\n" + "\n".join(wrong)


@pytest.mark.parametrize("package", sorted(PART_LEVELS))
def test_every_part_of_a_package_has_a_level(package):
    parts = {part_of(package, p) for p in part_modules(package)}
    known = set().union(*PART_LEVELS[package])
    assert parts <= known, f"give these a level in PART_LEVELS[{package!r}]: {sorted(parts - known)}"


@pytest.mark.parametrize("package", sorted(PART_LEVELS))
def test_no_import_cycle_between_the_parts_of_a_package(package):
    graph: dict[str, set[str]] = {}
    for path in part_modules(package):
        own = part_of(package, path)
        graph.setdefault(own, set()).update(t for _, t in part_imports(package, path) if t != own)
    done: set[str] = set()

    def visit(part: str, path: list[str]) -> list[str] | None:
        if part in path:
            return path[path.index(part):] + [part]
        if part in done:
            return None
        for nxt in sorted(graph.get(part, ())):
            cycle = visit(nxt, path + [part])
            if cycle:
                return cycle
        done.add(part)
        return None

    for part in sorted(graph):
        cycle = visit(part, [])
        assert cycle is None, f"import cycle between parts of {package}: " + " -> ".join(cycle)


def imported_modules(path: Path) -> list[tuple[int, str]]:
    """(line, dotted name) of every module a file imports, at any depth: ``from a import b``
    gives both ``a`` and ``a.b`` (b may be a module); relative imports are resolved."""
    package = ".".join(path.relative_to(ROOT).parent.parts)
    out = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            out += [(node.lineno, a.name) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parent = package.split(".")[:len(package.split(".")) - node.level + 1]
                base = ".".join(parent + ([base] if base else []))
            out += [(node.lineno, base)] + [(node.lineno, f"{base}.{a.name}") for a in node.names]
    return out


def test_no_test_module_imports_another_test_module_or_conftest():
    """Shared helpers live in tests/support/; fixtures come from conftest.py through pytest."""
    wrong = []
    for path in sorted((ROOT / "tests").rglob("*.py")):
        for line, name in imported_modules(path):
            last = name.split(".")[-1]
            if name.startswith("tests.") and (last.startswith("test_") or last == "conftest"):
                wrong.append(f"{path.relative_to(ROOT)}:{line}: imports {name}")
    assert not wrong, "import shared helpers from tests/support/ instead:\n" + "\n".join(wrong)


def test_the_test_helpers_hold_no_tests():
    """A module named test_*.py holds tests; helpers sit in tests/support/ under other names."""
    named_like_tests = sorted(p.name for p in (ROOT / "tests" / "support").rglob("test_*.py"))
    assert not named_like_tests, named_like_tests
    for path in sorted((ROOT / "tests").glob("test_*.py")):
        tree = ast.parse(path.read_text(), str(path))
        tests = [n for n in tree.body if isinstance(n, (ast.FunctionDef, ast.ClassDef))
                 and n.name.startswith(("test", "Test"))]
        assert tests, f"{path.relative_to(ROOT)} holds no tests: move it to tests/support/"
