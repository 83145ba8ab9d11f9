"""Every Python code block of the README and of the documentation site runs, as a reader would run it.

The blocks of one page run in order, as one script, in a fresh interpreter (so ``import silfit`` comes
first, as the pages say) whose working folder is a temporary one holding a link to the checkout's
``data/`` (the shipped subjects the examples read). A block is left out only when the line before its
fence is ``<!-- illustrative -->`` (code for another program, e.g. Blender's ``bpy``); most must run.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
ILLUSTRATIVE = "<!-- illustrative -->"
FENCE = re.compile(r"^```python[^\n]*\n(.*?)^```", re.S | re.M)


def python_blocks(text: str) -> tuple[list[str], list[str]]:
    """``(runnable, illustrative)`` Python blocks of a Markdown text, in order."""
    runnable, illustrative = [], []
    for match in FENCE.finditer(text):
        before = text[: match.start()].rstrip().splitlines()
        (illustrative if before and before[-1].strip() == ILLUSTRATIVE else runnable).append(match.group(1))
    return runnable, illustrative


def pages() -> list[Path]:
    return [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]


PAGES_WITH_CODE = [p for p in pages() if python_blocks(p.read_text())[0]]


def test_the_block_finder_sees_fences_and_marks():
    text = "a\n```python\nx = 1\n```\n\n<!-- illustrative -->\n```python\nimport bpy\n```\n```bash\nls\n```\n"
    assert python_blocks(text) == (["x = 1\n"], ["import bpy\n"])


def test_most_blocks_run():
    runnable = illustrative = 0
    for page in pages():
        r, i = python_blocks(page.read_text())
        runnable, illustrative = runnable + len(r), illustrative + len(i)
    assert runnable >= 8 and illustrative <= runnable // 4, (runnable, illustrative)
    assert ROOT / "README.md" in PAGES_WITH_CODE


@pytest.mark.parametrize("page", PAGES_WITH_CODE, ids=lambda p: str(p.relative_to(ROOT)))
def test_page_code_runs(page, tmp_path):
    blocks, _ = python_blocks(page.read_text())
    script = tmp_path / "page.py"
    script.write_text("\n".join(f"# --- block {k + 1}\n{b}" for k, b in enumerate(blocks)))
    (tmp_path / "data").symlink_to(ROOT / "data")
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]).rstrip(os.pathsep))
    run = subprocess.run(
        [sys.executable, str(script)], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600
    )
    assert run.returncode == 0, f"{page.relative_to(ROOT)}:\n{run.stdout[-2000:]}\n{run.stderr[-4000:]}"
