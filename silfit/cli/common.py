"""What several ``silfit fit`` modes share on the command line: the silhouette stage's
flags and writing an output folder that leaves nothing behind on failure."""

from __future__ import annotations

from pathlib import Path

from . import CLIError


def silhouette_config(args):
    """The silhouette stage's settings from ``--silhouette-resolutions`` / ``--silhouette-iterations`` and
    ``--silhouette-option NAME=VALUE`` (:func:`silhouette_options`), read as ``fit-dataset`` reads them
    (:func:`silfit.runner.worker.silhouette_config`)."""
    from ..runner.worker import FitOptions, silhouette_config as from_options

    options = FitOptions(
        silhouette_resolutions=args.silhouette_resolutions,
        silhouette_iterations=args.silhouette_iterations,
        silhouette_options=silhouette_options(args),
    )
    try:
        return from_options(options)
    except ValueError as err:
        raise CLIError(str(err)) from None


def keypoint_settings(args, base=None):
    """The keypoint stage's settings: ``base`` (``None``: the default) with ``--keypoint-option NAME=VALUE``
    overrides (:func:`keypoint_options`); ``base`` itself when none is given."""
    from ..runner.worker import keypoint_config

    overrides = keypoint_options(args)
    return keypoint_config(overrides, base) if overrides else base


def keypoint_options(args, refused: tuple = ()) -> dict:
    """``--keypoint-option NAME=VALUE`` flags (repeatable; ``silfit fit`` and ``fit-dataset`` alike) as
    ``{name: value}``, each checked against :class:`~silfit.fitting.keypoint_stage.KeypointFitConfig`; a bad
    one, or one of ``refused`` (a field a command sets with its own flag), is a :class:`CLIError`."""
    from ..fitting.keypoint_stage import KeypointFitConfig

    return _stage_options(getattr(args, "keypoint_option", None), KeypointFitConfig, "keypoint", refused)


def silhouette_options(args) -> dict:
    """``--silhouette-option NAME=VALUE`` flags (repeatable) as ``{name: value}``, each checked against
    :class:`~silfit.fitting.silhouette_stage.SilhouetteFitConfig` (``resolutions`` and ``iterations`` have their
    own flags); a bad one is a :class:`CLIError`."""
    from ..fitting.silhouette_stage import SilhouetteFitConfig

    refused = {"resolutions": "silhouette-resolutions", "iterations": "silhouette-iterations"}
    return _stage_options(getattr(args, "silhouette_option", None), SilhouetteFitConfig, "silhouette", refused)


def _stage_options(texts, cls, stage: str, refused=()) -> dict:
    """``--<stage>-option NAME=VALUE`` flags ``texts`` as ``{name: value}``, checked against ``cls``
    (:func:`silfit.runner.worker.config_with`); ``refused``: names given by their own flag (a mapping: to that
    flag's name)."""
    from ..runner.worker import config_with

    overrides = {}
    for text in texts or ():
        name, sep, value = text.partition("=")
        if not sep or not name:
            raise CLIError(f"--{stage}-option {text!r}: expected NAME=VALUE")
        overrides[name.strip()] = value.strip()
        if name.strip() in refused:
            flag = refused[name.strip()] if isinstance(refused, dict) else name.strip()
            raise CLIError(f"--{stage}-option {text!r}: give --{flag} instead")
    try:
        config_with(cls, overrides, None, stage)
    except ValueError as err:
        raise CLIError(str(err)) from None
    return overrides


def check_out(out, overwrite: bool) -> None:
    """An output folder that exists and is not empty is refused unless ``--overwrite`` was given (its one meaning,
    :data:`silfit.cli.flags.MEANINGS`)."""
    out = Path(out)
    if out.exists() and not overwrite and (not out.is_dir() or any(out.iterdir())):
        raise CLIError(f"{out}: output folder exists and is not empty (use --overwrite)")


def _missing_folders(path: Path) -> list:
    """``path``'s ancestors that do not exist yet, deepest first (removed again on failure)."""
    missing, parent = [], path.absolute().parent
    while not parent.exists():
        missing.append(parent)
        parent = parent.parent
    return missing


def save_leaving_nothing_on_error(out: Path, save) -> None:
    """``save()`` (writes the folder ``out``); on an error or an interrupt, the parent folders
    this run created are removed again (the writers themselves are atomic)."""
    created = _missing_folders(out)
    try:
        save()
    except BaseException:
        for folder in created:
            if folder.is_dir() and not any(folder.iterdir()):
                folder.rmdir()
        raise


def choose_model(choice, gender: str, has_parts: bool):
    """``(model, note)``: ``--model`` (a file or folder, or ``open-smplx``), else the shipped open
    whole-body model when the keypoints have hand or face points (with a note saying so), else the
    shipped open body model."""
    from .. import load_body_model

    if choice == "open-smplx":
        return load_body_model(kind="smplx"), None
    if choice:
        return load_body_model(choice, gender=gender), None
    if has_parts:
        model = load_body_model(kind="smplx")
        return (
            model,
            f"keypoints have hand/face points and no --model: using the shipped open whole-body model ({model.source})",
        )
    return load_body_model(), None


def export_formats(args) -> tuple:
    """``--export``'s formats (``CLIError`` for an unknown one)."""
    from ..outputs.export import parse_formats

    try:
        return parse_formats(getattr(args, "export", None))
    except ValueError as err:
        raise CLIError(str(err)) from None
