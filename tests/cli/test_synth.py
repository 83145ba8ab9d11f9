"""``silfit synth`` from the command line."""

import json

from silfit.cli import main


def test_synth_writes_a_dataset(tmp_path, capsys):
    out = tmp_path / "ds"
    code = main(
        [
            "synth",
            "--n",
            "2",
            "--seed",
            "4",
            "--out",
            str(out),
            "--size",
            "96",
            "--noise-px",
            "1.5",
            "--clean",
            "1",
            "--drop",
            "0.1",
            "--quiet",
            "--coco",
        ]
    )
    assert code == 0
    index = json.loads((out / "index.json").read_text())
    assert index["generator"]["seed"] == 4 and index["generator"]["noise_px"] == 1.5
    assert index["generator"]["command"].startswith("silfit synth --n 2 --seed 4")
    assert (out / "subject_001" / "keypoints_coco17.json").is_file()
    text = capsys.readouterr().out
    assert "wrote 2 subjects" in text and "stature" in text and "yaw" in text


def test_synth_bad_arguments_are_one_line_errors(tmp_path, capsys):
    assert main(["synth", "--n", "0", "--out", str(tmp_path / "x"), "--quiet"]) == 2
    assert "error: --n must be a positive" in capsys.readouterr().err
    assert main(["synth", "--n", "1", "--out", str(tmp_path / "x"), "--noise-px", "-1"]) == 2
    assert "--noise-px must be >= 0" in capsys.readouterr().err


def test_synth_whole_body_with_a_body_only_model_is_a_one_line_error(tmp_path, capsys):
    from silfit.body.io import OPEN_BODY_PATH

    out = tmp_path / "wb"
    assert (
        main(["synth", "--whole-body", "--n", "1", "--out", str(out), "--model", str(OPEN_BODY_PATH), "--quiet"]) == 2
    )
    err = capsys.readouterr().err
    assert "--whole-body needs an SMPL-X-layout model" in err and len(err.strip().splitlines()) == 1
    assert not (out / "subject_000").exists()


def test_synth_hard_poses(tmp_path, capsys):
    out = tmp_path / "hard"
    assert (
        main(["synth", "--poses", "hard", "--n", "1", "--seed", "3", "--out", str(out), "--size", "64", "--quiet"]) == 0
    )
    index = json.loads((out / "index.json").read_text())
    assert index["generator"]["poses"] == "hard" and "--poses hard" in index["generator"]["command"]
    from silfit.poses.sampler import ARCHETYPES

    assert index["subjects"][0]["pose"] in ARCHETYPES
