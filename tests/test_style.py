"""Style is enforced, not asked for: ``ruff format --check`` and ``ruff check`` (configured in pyproject.toml,
line length 120) pass on the whole repository, and no function in the package is over 80 lines."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
MAX_FUNCTION_LINES = 80


def _ruff(*args: str) -> subprocess.CompletedProcess:
    import ruff  # noqa: F401  (in the test extra: a missing ruff fails the style tests, it does not skip them)

    return subprocess.run([sys.executable, "-m", "ruff", *args], cwd=ROOT, capture_output=True, text=True)


def test_the_code_is_formatted():
    out = _ruff("format", "--check", ".")
    assert out.returncode == 0, "run `ruff format .`:\n" + out.stdout + out.stderr


def test_the_linter_passes():
    out = _ruff("check", "--output-format", "concise", ".")
    assert out.returncode == 0, out.stdout + out.stderr


def test_no_per_line_formatter_exceptions():
    marked = [
        f"{p.relative_to(ROOT)}:{i}"
        for top in ("silfit", "tests", "benchmarks", "tools")
        for p in sorted((ROOT / top).rglob("*.py"))
        for i, line in enumerate(p.read_text(encoding="utf-8").splitlines(), 1)
        if "fmt: " + "skip" in line or "fmt: " + "off" in line
    ]
    assert not marked, marked


def long_functions(root: Path = ROOT / "silfit", limit: int = MAX_FUNCTION_LINES) -> list:
    """``path:line name (lines)`` of every function in ``root`` longer than ``limit`` lines (docstring included)."""
    found = []
    for p in sorted(root.rglob("*.py")):
        for node in ast.walk(ast.parse(p.read_text(encoding="utf-8"))):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                n = node.end_lineno - node.lineno + 1
                if n > limit:
                    found.append(f"{p.relative_to(root.parent)}:{node.lineno} {node.name} ({n})")
    return found


def test_no_function_over_80_lines():
    assert not long_functions(), long_functions()


def test_the_length_check_sees_a_long_function(tmp_path):
    body = "".join(f"    x{i} = {i}\n" for i in range(MAX_FUNCTION_LINES))
    (tmp_path / "m.py").write_text("def short():\n    return 1\n\n\ndef long():\n" + body)
    assert long_functions(tmp_path) == [f"{tmp_path.name}/m.py:5 long ({MAX_FUNCTION_LINES + 1})"]


def private_imports(root: Path = ROOT / "silfit") -> list:
    """``path:line module.name`` of every ``from module import _name`` in ``root``: another module's private name."""
    found = []
    for p in sorted(root.rglob("*.py")):
        for node in ast.walk(ast.parse(p.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom):
                for alias in node.names:
                    if alias.name.startswith("_") and not alias.name.startswith("__"):
                        found.append(f"{p.relative_to(root.parent)}:{node.lineno} {node.module}.{alias.name}")
    return found


def test_no_import_of_another_modules_private_name():
    assert not private_imports(), private_imports()


def test_the_private_import_check_sees_one(tmp_path):
    (tmp_path / "m.py").write_text("from .other import _hidden, shown\n")
    assert private_imports(tmp_path) == [f"{tmp_path.name}/m.py:1 other._hidden"]


def test_one_installed_package_with_few_top_level_modules():
    """The layout shows the flow (issue 57): one top-level package, its top level a handful of modules, the rest in
    packages by role (io, fitting, outputs, render, ...)."""
    import tomllib

    find = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"]["find"]
    assert find["include"] == ["silfit*"]
    top = sorted(p.name for p in (ROOT / "silfit").glob("*.py"))
    assert len(top) <= 10, top


def _module_exists(dotted: str) -> bool:
    p = ROOT.joinpath(*dotted.split("."))
    return p.with_suffix(".py").is_file() or (p / "__init__.py").is_file()


def _names_defined(init: Path) -> set:
    """The names a package's ``__init__.py`` defines, imports or exports lazily (names in its strings)."""
    names = set()
    for node in ast.walk(ast.parse(init.read_text(encoding="utf-8"))):
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            names |= {(a.asname or a.name).split(".")[0] for a in node.names}
        elif isinstance(node, (ast.FunctionDef, ast.ClassDef)):
            names.add(node.name)
        elif isinstance(node, ast.Name) and isinstance(node.ctx, ast.Store):
            names.add(node.id)
        elif isinstance(node, ast.Constant) and isinstance(node.value, str) and node.value.isidentifier():
            names.add(node.value)  # __all__ and the lazy exports' tables
    return names


def unresolved_imports(root: Path = ROOT) -> list:
    """``path:line module`` of every import of a silfit module (absolute or relative, at module level or inside a
    function, where only running it would find a wrong one) whose module is not in the tree."""
    found = []
    for top in ("silfit", "tests", "benchmarks", "tools"):
        for p in sorted((root / top).rglob("*.py")):
            package = list(p.relative_to(root).with_suffix("").parts[:-1])
            for node in ast.walk(ast.parse(p.read_text(encoding="utf-8"))):
                if isinstance(node, ast.ImportFrom):
                    if node.level:
                        base = package[: len(package) - node.level + 1]
                        names = [".".join(base + ([node.module] if node.module else []))]
                    else:
                        names = [node.module or ""]
                    init = ROOT.joinpath(*names[0].split("."), "__init__.py")
                    if names[0].split(".")[0] == "silfit" and init.is_file():  # from a package: a module or a name
                        defined = _names_defined(init)
                        names += [f"{names[0]}.{a.name}" for a in node.names if a.name not in defined]
                elif isinstance(node, ast.Import):
                    names = [a.name for a in node.names]
                else:
                    continue
                found += [
                    f"{p.relative_to(root)}:{node.lineno} {m}"
                    for m in names
                    if m.split(".")[0] == "silfit" and not _module_exists(m)
                ]
    return found


def test_every_silfit_import_resolves():
    assert not unresolved_imports(), unresolved_imports()


def test_moved_modules_still_import_under_their_old_names():
    """Scripts written against the layout before issue 57 keep running for a release: each old name is the new
    module itself, with a DeprecationWarning naming the new place."""
    import importlib

    import silfit

    for old, new in silfit.MOVED_MODULES.items():
        assert _module_exists(new) and not _module_exists(old), (old, new)
        with pytest.warns(DeprecationWarning, match=f"{old} moved to {new}"):
            sys.modules.pop(old, None)
            assert importlib.import_module(old) is importlib.import_module(new)
        sys.modules.pop(old, None)


def test_an_old_module_name_warns_where_the_script_imports_it(tmp_path):
    """The DeprecationWarning points at the script's line, so Python's default filters show it (a warning
    attributed to the import machinery would be hidden)."""
    script = tmp_path / "old.py"
    script.write_text("import silfit.dataset\n")
    out = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    assert "old.py:1: DeprecationWarning: silfit.dataset moved to silfit.io.subjects" in out.stderr
