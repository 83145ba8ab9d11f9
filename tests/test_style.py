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
    pytest.importorskip("ruff", reason="ruff is in the test extra")
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
