"""Atomic output folders: what a failed swap leaves behind."""
import os
import subprocess

import pytest

from silfit.outfolder import atomic_folder


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
