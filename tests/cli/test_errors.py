"""How the command line reports errors of the system: the file (or the output folder) named."""

import os

import pytest

import silfit.cli.detect
from silfit.cli import main


def test_a_full_disk_names_the_output_folder(tmp_path, monkeypatch, capsys):
    if not os.path.exists("/dev/full"):
        pytest.skip("no /dev/full")

    def write_to_a_full_disk(args):  # a writer whose data does not fit: the kernel's ENOSPC, with no file name
        with open("/dev/full", "wb") as fh:
            fh.write(b"x" * 1_000_000)

    monkeypatch.setattr(silfit.cli.detect, "run", write_to_a_full_disk)
    out = tmp_path / "det"
    assert main(["detect", "photo.jpg", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert err == f"silfit detect: error: {out}: No space left on device (writing the output)", err


def test_an_error_of_the_system_names_its_file(tmp_path, monkeypatch, capsys):
    def read_a_folder(args):
        open(tmp_path).read()

    monkeypatch.setattr(silfit.cli.detect, "run", read_a_folder)
    assert main(["detect", "photo.jpg", "--out", str(tmp_path / "o")]) == 2
    assert capsys.readouterr().err.strip() == f"silfit detect: error: {tmp_path}: Is a directory"
