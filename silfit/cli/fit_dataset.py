"""``silfit fit-dataset INPUT --out OUT``: fit every image (and person) of a dataset.

INPUT is an OpenPose output folder, a manifest (``.jsonl`` / ``.csv``) or a dataset in
silfit's synthetic format (see :mod:`silfit.runner.items`). OUT gets one folder per
(image, person) in ``silfit fit``'s layout, ``results.jsonl``, ``failures.jsonl``,
``summary.md``, ``summary.json``, ``summary.png`` (see :mod:`silfit.runner.store`) and
``report/index.html`` (a gallery of the fits, :mod:`silfit.outputs.report`; not with ``--no-report``).
Rerunning with the same OUT skips finished items (``--retry-failed`` retries the failed).

Exit status: 0 every item fitted; 2 the command or the input as a whole is wrong (nothing
is fitted); ``10 + n`` when ``n`` items failed (``n`` capped at 100, so 110 means 100 or
more); ``failures.jsonl`` says which and why.
"""

from __future__ import annotations

import sys

from . import CLIError

#: Exit status offset for failed items: status = FAILED_BASE + min(failed, FAILED_CAP).
FAILED_BASE, FAILED_CAP = 10, 100


def exit_status(failed: int) -> int:
    return 0 if failed == 0 else FAILED_BASE + min(int(failed), FAILED_CAP)


def _add_input_flags(p) -> None:
    """The dataset, the output folder and which people of each image."""
    p.add_argument(
        "input", help="OpenPose folder (*_keypoints.json), manifest (.jsonl/.csv) or synthetic dataset folder"
    )
    p.add_argument("--out", required=True, help="output folder (created; an existing one is resumed)")
    p.add_argument(
        "--people",
        default="largest",
        metavar="largest|all",
        help="largest (default): the largest person of each image; all: every person",
    )
    p.add_argument(
        "--person",
        type=int,
        default=None,
        metavar="K",
        help="person K of each image instead (0-based, as silfit fit --person)",
    )


def _add_openpose_flags(p) -> None:
    """An OpenPose input's masks, images and cameras, and one focal length for every item."""
    p.add_argument("--masks", help="OpenPose input: folder of <stem>.png / <stem>_<k>.png masks")
    p.add_argument("--images", help="OpenPose input: folder of <stem>.png/.jpg images")
    p.add_argument("--camera", help="OpenPose input: a shared camera.json, or a folder of <stem>.json")
    p.add_argument("--focal", type=float, help="focal length in pixels for every item (overrides the cameras')")


def _add_fit_flags(p) -> None:
    """The batch size, the stages, retrying failed items, the body model and the pose prior."""
    p.add_argument("--batch-size", type=int, default=8, help="items per keypoint-stage batch (default 8)")
    p.add_argument("--no-silhouette", action="store_true", help="keypoint stage only, even where masks exist")
    p.add_argument("--retry-failed", action="store_true", help="fit again the items failed in a previous run")
    p.add_argument(
        "--model",
        help="SMPL or SMPL-X model file or folder, or 'open-smplx' (the shipped open whole-body "
        "model: hands and face of OpenPose whole-body files are fitted) (default: the shipped open body model)",
    )
    p.add_argument("--gender", default="neutral", help="model gender when --model is a folder")
    p.add_argument("--pose-prior", help="pose prior: gmm_08.pkl, a mixture .npz, or 'limits' (default: shipped)")


def _add_stage_option_flags(p) -> None:
    """The keypoint and silhouette stages' overrides and the silhouette stage's levels."""
    p.add_argument(
        "--keypoint-option",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="override a KeypointFitConfig field, e.g. starts.poses=1 or pose_iters=10,10,10 (repeatable)",
    )
    p.add_argument(
        "--silhouette-option",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="override a SilhouetteFitConfig field, e.g. alternatives_margin=0 (repeatable)",
    )
    p.add_argument(
        "--silhouette-resolutions", metavar="R1,R2", help="silhouette window sizes per level (default 128,256)"
    )
    p.add_argument(
        "--silhouette-iterations",
        metavar="N1,N2",
        help="silhouette rendered steps per level (default 30,20, after the contour level)",
    )


def _add_worker_flags(p) -> None:
    """Where the items are fitted: local worker processes or Ray actors."""
    p.add_argument(
        "--workers",
        default="1",
        metavar="N|auto",
        help="local worker processes, one CPU each, the same fits as one (default 1; auto: one per CPU)",
    )
    p.add_argument(
        "--ray",
        nargs="?",
        const="",
        default=None,
        metavar="ADDRESS",
        help="run on Ray: no ADDRESS starts a local Ray, else join that cluster (e.g. auto, ray://head:10001)",
    )
    p.add_argument("--actors", type=int, default=2, help="Ray: fitting actors (default 2)")
    p.add_argument("--num-cpus", type=float, default=1.0, help="Ray: CPUs reserved per actor (default 1)")
    p.add_argument("--num-gpus", type=float, default=0.0, help="Ray: GPUs reserved per actor (default 0)")


def _add_output_flags(p) -> None:
    """What is written besides the fits, and the progress bar."""
    p.add_argument(
        "--export",
        metavar="glb,ply",
        help="also write mesh.glb / mesh.ply per item: the body upright "
        "(x right, y up, z toward the viewer), normals, the camera in the glTF",
    )
    p.add_argument(
        "--no-report",
        action="store_true",
        help="do not write report/index.html (the gallery of `silfit report`) at the end",
    )
    p.add_argument(
        "--quiet", action="store_true", help="no progress bar (the summary table and warnings are still printed)"
    )


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "fit-dataset",
        help="fit a whole dataset: OpenPose folder, manifest or synthetic set (resumable; local or Ray)",
        description=__doc__.split("\n\n", 1)[1],
        epilog="exit status: 0 all fitted, 2 bad command/input, 10+n n items failed (n<=100)",
    )
    _add_input_flags(p)
    _add_openpose_flags(p)
    _add_fit_flags(p)
    _add_stage_option_flags(p)
    _add_worker_flags(p)
    _add_output_flags(p)
    p.set_defaults(func=run)


def _ints(text, option):
    if text is None:
        return None
    try:
        values = tuple(int(v) for v in text.split(","))
    except ValueError:
        raise CLIError(f"{option} {text!r}: expected comma-separated integers") from None
    if not values or min(values) <= 0:
        raise CLIError(f"{option} {text!r}: expected positive integers")
    return values


def _workers(text: str):
    if text == "auto":
        return text
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise CLIError(f"--workers {text!r}: expected a positive number of processes or auto")
    return value


def _checked_workers(args):
    """``--workers`` (checked), after the batch size and the local / Ray flags are checked against each other."""
    if args.batch_size < 1:
        raise CLIError(f"--batch-size {args.batch_size}: expected 1 or more")
    workers = _workers(args.workers)
    if args.ray is not None and workers != 1:
        raise CLIError("--workers runs local processes; a Ray run has --actors")
    if args.ray is None and (args.actors != 2 or args.num_cpus != 1.0 or args.num_gpus != 0.0):
        raise CLIError("--actors, --num-cpus and --num-gpus are Ray options: add --ray")
    return workers


def _people(args):
    """``--people`` / ``--person`` as :func:`silfit.runner.items.parse_people` reads them (``--people K``, the old
    spelling of ``--person K``, with a deprecation warning)."""
    from ..runner import InputError
    from ..runner.items import parse_people

    try:
        if args.person is not None and args.people != "largest":
            raise CLIError(f"--people {args.people} and --person {args.person}: give one of them")
        if args.people.strip().isdigit():  # the old spelling of --person K
            print(
                f"warning: --people {args.people} is deprecated, use --person {args.people} (same meaning)",
                file=sys.stderr,
            )
            args.person, args.people = args.people, "largest"
        return parse_people(args.people if args.person is None else str(args.person))
    except (InputError, ValueError) as err:
        raise CLIError(str(err)) from None


def _fit_options(args):
    """The :class:`silfit.runner.FitOptions` of every item, from the model, stage and export flags."""
    from ..runner import FitOptions
    from .common import keypoint_options, silhouette_options

    overrides = keypoint_options(args)
    from ..outputs.export import parse_formats

    try:
        exports = parse_formats(args.export)
    except ValueError as err:
        raise CLIError(str(err)) from None
    return FitOptions(
        exports=list(exports),
        model=args.model,
        gender=args.gender,
        pose_prior=args.pose_prior,
        silhouette=not args.no_silhouette,
        focal=args.focal,
        keypoint_options=overrides,
        silhouette_options=silhouette_options(args),
        silhouette_resolutions=_ints(args.silhouette_resolutions, "--silhouette-resolutions"),
        silhouette_iterations=_ints(args.silhouette_iterations, "--silhouette-iterations"),
    )


def _write_report(out) -> None:
    """``OUT/report/index.html`` (:func:`silfit.outputs.report.write_report`); one that cannot be written is a
    warning (the fits are written), unless the run was stopped while writing it."""
    from ..errors import interruption
    from ..outputs.report import write_report

    try:
        index = write_report(out)
    except (OSError, ValueError) as err:  # the fits are written; a report that cannot be is a warning
        if interruption(err) is not None:  # (unless the run was stopped while writing it)
            raise
        print(f"silfit fit-dataset: warning: no report: {' '.join(str(err).split())}", file=sys.stderr)
    else:
        print(f"wrote {index} (open it in a browser)")


def run(args) -> int:
    from ..runner import InputError, fit_dataset

    workers = _checked_workers(args)
    people = _people(args)
    options = _fit_options(args)
    try:
        summary = fit_dataset(
            args.input,
            args.out,
            people=people,
            masks=args.masks,
            images=args.images,
            camera=args.camera,
            options=options,
            batch_size=args.batch_size,
            retry_failed=args.retry_failed,
            workers=workers,
            ray=args.ray is not None,
            ray_address=args.ray or None,
            actors=args.actors,
            num_cpus=args.num_cpus,
            num_gpus=args.num_gpus,
            progress=not args.quiet,
        )
    except InputError as err:
        raise CLIError(str(err)) from None
    if not args.no_report:
        _write_report(args.out)
    print(summary["table"])
    if summary["failed"]:
        print(
            f"silfit fit-dataset: {summary['failed']} of {summary['items']} items failed; see {args.out}/failures.jsonl",
            file=sys.stderr,
        )
    return exit_status(summary["failed"])
