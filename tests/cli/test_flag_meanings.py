"""One meaning per flag: every subcommand's parser walked, the renamed flags' old spellings, examples in
every ``--help``, suggestions for a mistyped stage option."""

import argparse

import pytest

from silfit.cli import SUBCOMMANDS, build_parser, main
from silfit.cli.flags import MEANINGS, is_deprecated


def subparsers():
    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return sub.choices


def uses():
    """``{flag: [(subcommand, action)]}`` of every option string but --help, old spellings left out."""
    found = {}
    for name, parser in subparsers().items():
        for action in parser._actions:
            if isinstance(action, argparse._HelpAction) or is_deprecated(action):
                continue
            for flag in action.option_strings:
                found.setdefault(flag, []).append((name, action))
    return found


def test_every_subcommand_is_walked():
    assert sorted(subparsers()) == sorted(SUBCOMMANDS)


def test_a_shared_flag_has_one_meaning():
    shared = {flag: where for flag, where in uses().items() if len(where) > 1}
    assert len(shared) >= 10
    unlisted = sorted(set(shared) - set(MEANINGS))
    assert not unlisted, f"flags several subcommands take, with no entry in silfit.cli.flags.MEANINGS: {unlisted}"
    for flag, where in shared.items():
        kinds = {
            (type(a).__name__, a.nargs) for _, a in where
        }  # a switch in one place, a value in another: two meanings
        assert len(kinds) == 1, f"{flag}: {[(n, type(a).__name__, a.nargs) for n, a in where]}"
    assert not set(MEANINGS) - set(shared), "an entry of MEANINGS no longer shared: remove it"


def test_the_flags_that_had_two_meanings_have_one():
    found = uses()
    assert [n for n, _ in found["--views"]] == ["fit"]  # a rig's camera names; synth --cameras, render --directions
    assert [n for n, _ in found["--layout"]] == ["detect"]  # a keypoint layout; synth --cameras-file
    assert "--no-progress" not in found and {n for n, _ in found["--quiet"]} >= {
        "fit",
        "detect",
        "synth",
        "eval",
        "demo",
    }
    assert all(a.metavar != "FILE" for _, a in found["--out"]), "--out is a folder everywhere (eval: --report FILE)"
    assert "--sequence" in found and [n for n, _ in found["--sequence"]] == ["fit"]  # a video folder; synth --videos
    assert [n for n, _ in found["--mask"]] == ["fit"]  # a mask file; render --write-mask


@pytest.mark.parametrize(
    "command, old, new, value",
    [
        ("synth", "--views", "--cameras", "3"),
        ("synth", "--layout", "--cameras-file", "c.json"),
        ("synth", "--sequence", "--videos", None),
        ("synth", "--no-progress", "--quiet", None),
        ("render", "--views", "--directions", "front,side"),
        ("render", "--mask", "--write-mask", None),
        ("eval", "--out", "--report", "r.json"),
    ],
)
def test_an_old_spelling_still_works_and_names_the_new_one(command, old, new, value, capsys):
    base = {"synth": ["synth", "--n", "1", "--out", "o"], "render": ["render", "p.npz"], "eval": ["eval", "d"]}[command]
    extra = [value] if value is not None else []
    parser = build_parser()
    assert vars(parser.parse_args(base + [old, *extra])) == vars(parser.parse_args(base + [new, *extra]))
    assert f"{old} is deprecated, use {new}" in capsys.readouterr().err


def test_fit_dataset_people_index_moves_to_person(tmp_path, capsys):
    # the old --people K still selects person K (and says --person K); a missing input then stops the run
    assert main(["fit-dataset", str(tmp_path / "missing"), "--people", "1", "--out", str(tmp_path / "o")]) == 2
    assert "--people 1 is deprecated, use --person 1" in capsys.readouterr().err
    args = build_parser().parse_args(["fit-dataset", "in", "--person", "2", "--out", "o"])
    assert args.person == 2 and args.people == "largest"


@pytest.mark.parametrize("command", SUBCOMMANDS)
def test_every_help_ends_with_examples_and_no_docstring_markup(command, capsys):
    with pytest.raises(SystemExit):
        main([command, "--help"])
    text = capsys.readouterr().out
    examples = text[text.index("examples:") :]
    assert examples.count(f"silfit {command}") >= 2, examples
    assert ":mod:" not in text and ":func:" not in text and "``" not in text


@pytest.mark.parametrize(
    "flag, typo, suggestion",
    [
        ("--keypoint-option", "init_pose=1", "init_poses"),
        ("--silhouette-option", "alternative_margin=0", "alternatives_margin"),
    ],
)
def test_a_mistyped_stage_option_gets_a_suggestion(flag, typo, suggestion, tmp_path, capsys):
    assert main(["fit", "--keypoints", str(tmp_path / "kp.json"), "--out", str(tmp_path / "o"), flag, typo]) == 2
    err = capsys.readouterr().err
    assert f"did you mean {suggestion}" in err and len(err.strip().splitlines()) == 1, err


def test_synth_and_export_model_refuse_a_non_empty_folder_without_overwrite(tmp_path, capsys):
    from silfit.cli import main

    (tmp_path / "data").mkdir()
    (tmp_path / "data" / "mine.txt").write_text("keep")
    assert main(["synth", "--n", "1", "--size", "32", "--out", str(tmp_path / "data"), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "use --overwrite" in err and err.count("\n") == 1 and (tmp_path / "data" / "mine.txt").exists()
    (tmp_path / "models" / "smpl").mkdir(parents=True)
    (tmp_path / "models" / "smpl" / "x").write_text("")
    assert main(["export-model", "smpl", str(tmp_path / "models")]) == 2
    assert not (tmp_path / "models" / "smpl" / "SMPL_NEUTRAL.pkl").exists()
    assert main(["export-model", "smpl", str(tmp_path / "models"), "--overwrite"]) == 0
    assert (tmp_path / "models" / "smpl" / "SMPL_NEUTRAL.pkl").exists()


def test_fit_dataset_refuses_people_with_person(tmp_path, capsys):
    from silfit.cli import main

    assert main(["fit-dataset", str(tmp_path), "--out", str(tmp_path / "o"), "--people", "all", "--person", "1"]) == 2
    err = capsys.readouterr().err
    assert "give one of them" in err and err.count("\n") == 1 and not (tmp_path / "o").exists()
