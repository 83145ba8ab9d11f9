"""Atomic output folders: what a failed swap leaves behind."""

import os
import subprocess

import pytest

from silfit.outputs.folder import atomic_folder


def _read_only(folder):
    """Make ``folder`` impossible to move: read-only for a user, immutable (chattr +i) for root."""
    if os.geteuid() != 0:
        folder.chmod(0o555)
        return lambda: folder.chmod(0o755)
    if subprocess.run(["chattr", "+i", str(folder)], capture_output=True).returncode != 0:
        pytest.skip("running as root on a file system without chattr +i: cannot make a folder read-only")
    return lambda: subprocess.run(["chattr", "-i", str(folder)], check=True)


def test_a_read_only_existing_output_folder_leaves_nothing_behind(tmp_path):
    out = tmp_path / "fit"
    out.mkdir()
    undo = _read_only(out)
    try:
        with pytest.raises(OSError) as info:
            with atomic_folder(out, overwrite=True) as tmp:
                (tmp / "params.json").write_text("{}")
        assert str(out) in str(info.value) and "cannot replace the existing output folder" in str(info.value)
        assert sorted(p.name for p in tmp_path.iterdir()) == ["fit"]  # no .fit.old.* nor .fit.* left
        assert out.is_dir() and not any(out.iterdir())
    finally:
        undo()


def test_the_earlier_output_is_replaced_only_once_complete(tmp_path):
    out = tmp_path / "fit"
    out.mkdir()
    (out / "old.txt").write_text("old")
    with pytest.raises(RuntimeError):
        with atomic_folder(out, overwrite=True) as tmp:
            (tmp / "new.txt").write_text("new")
            raise RuntimeError("the writer failed")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["fit"] and (out / "old.txt").is_file()
    with atomic_folder(out, overwrite=True) as tmp:
        (tmp / "new.txt").write_text("new")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["fit"] and sorted(os.listdir(out)) == ["new.txt"]


@pytest.mark.parametrize("when", ["staging", "set-aside", "swap", "cleanup"])
def test_an_interrupt_at_any_point_leaves_one_output_and_nothing_else(tmp_path, monkeypatch, when):
    """A signal can land as soon as ``mkdir`` returns (``silfit fit`` was seen leaving ``.fit.*`` behind): the
    staging and set-aside folders are named before they exist, so the cleanup knows them; an interrupt
    between setting the earlier output aside and the swap puts it back; one while the earlier output is
    deleted after the swap leaves the new output and removes the rest."""
    import silfit.outputs.folder as outfolder

    out = tmp_path / "fit"
    out.mkdir()
    (out / "old.txt").write_text("earlier")
    real_mkdir, real_replace, real_rmtree = os.mkdir, os.replace, outfolder.shutil.rmtree
    made, removing = [], []

    def mkdir(path, mode=0o777):
        real_mkdir(path, mode)
        made.append(path)
        if (when == "staging" and len(made) == 1) or (when == "set-aside" and len(made) == 2):
            raise KeyboardInterrupt

    def replace(src, dst):
        real_replace(src, dst)
        if when == "swap" and dst != out:  # the earlier output is set aside: interrupted before the swap
            raise KeyboardInterrupt

    def rmtree(path, ignore_errors=False):
        removing.append(path)
        if when == "cleanup" and len(removing) == 1:  # interrupted before deleting anything
            raise KeyboardInterrupt
        real_rmtree(path, ignore_errors=ignore_errors)

    monkeypatch.setattr(outfolder.os, "mkdir", mkdir)
    monkeypatch.setattr(outfolder.os, "replace", replace)
    monkeypatch.setattr(outfolder.shutil, "rmtree", rmtree)
    with pytest.raises(KeyboardInterrupt):
        with atomic_folder(out, overwrite=True) as tmp:
            (tmp / "new.txt").write_text("new")
    monkeypatch.undo()
    assert made and sorted(p.name for p in tmp_path.iterdir()) == ["fit"]
    assert sorted(p.name for p in out.iterdir()) == (["new.txt"] if when == "cleanup" else ["old.txt"])
