"""The documentation site builds with warnings as errors (``mkdocs build --strict``, as ``mkdocs.yml``
sets it): a broken link between pages, a missing anchor or image, a page left out of the navigation, or an
API reference entry naming a function or module that no longer exists fails the suite.

MkDocs, Material, mkdocstrings and mkdocs-awesome-nav come with the ``docs`` extra, which
``tools/setup.sh`` installs; without them this test fails (it is not skipped) and says what to install.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def build(tmp_path: Path, edit=None) -> subprocess.CompletedProcess:
    """``mkdocs build --strict`` of a copy of ``docs/`` and ``mkdocs.yml`` (``edit(docs_copy)`` may change
    the copy first), with the API reference read from this checkout's sources."""
    try:
        import material  # noqa: F401
        import mkdocs  # noqa: F401
        import mkdocs_awesome_nav  # noqa: F401
        import mkdocstrings  # noqa: F401
    except ImportError as err:
        pytest.fail(
            f"{err}: the docs build needs the docs extra: pip install -c constraints.txt -e '.[docs]' "
            "(tools/setup.sh installs it)"
        )
    shutil.copytree(ROOT / "docs", tmp_path / "docs")
    config = (ROOT / "mkdocs.yml").read_text()
    assert "paths: [.]" in config
    (tmp_path / "mkdocs.yml").write_text(config.replace("paths: [.]", f"paths: [{ROOT}]"))
    if edit:
        edit(tmp_path / "docs")
    env = dict(os.environ, NO_MKDOCS_2_WARNING="1")  # no advertisement of Material's successor on stderr
    return subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(tmp_path / "site")],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=600,
        env=env,
    )


def test_the_site_builds_with_warnings_as_errors(tmp_path):
    run = build(tmp_path)
    assert run.returncode == 0, run.stderr[-4000:]
    site = tmp_path / "site"
    for page in (
        "index.html",
        "install/index.html",
        "how-it-works/index.html",
        "guides/photos/index.html",
        "benchmarks/depth-ambiguity/index.html",
        "reference/silfit-run/index.html",
    ):
        assert (site / page).is_file(), page
    api = (site / "reference/silfit-run/index.html").read_text()
    assert "image_job" in api and "run_batch" in api  # generated from the docstrings
    assert "SilhouetteFitConfig" in (site / "reference/silfit-fitting/index.html").read_text()


def test_a_new_page_appears_in_the_navigation_by_itself(tmp_path):
    # other branches add guides and reports (docs/guides/<topic>.md, docs/benchmarks/<topic>.md) without a nav edit
    def add(docs):
        (docs / "guides" / "zz-new-topic.md").write_text("# A new guide\n\nText.\n")
        (docs / "benchmarks" / "zz-new-report.md").write_text("# A new report\n\nText.\n")

    run = build(tmp_path, add)
    assert run.returncode == 0, run.stderr[-4000:]
    home = (tmp_path / "site" / "index.html").read_text()
    assert "A new guide" in home and "A new report" in home


@pytest.mark.parametrize("breakage", ["link", "api"])
def test_a_broken_reference_fails_the_build(tmp_path, breakage):
    def break_it(docs):
        page = docs / "guides" / "photos.md"
        if breakage == "link":
            page.write_text(page.read_text() + "\nSee [nowhere](no-such-page.md).\n")
        else:  # a renamed function: the reference names what no longer exists
            (docs / "reference" / "silfit-run.md").write_text("# run\n\n::: silfit.run.no_such_function\n")

    run = build(tmp_path, break_it)
    assert run.returncode != 0
    assert ("no-such-page.md" if breakage == "link" else "no_such_function") in run.stderr
