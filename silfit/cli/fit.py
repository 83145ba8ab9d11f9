"""``silfit fit``: SMPL / SMPL-X from keypoints (one image or photo, a calibrated rig, or a
video), refined against the person's silhouettes.

The flags make a job (:mod:`silfit.cli.jobs`), :func:`silfit.run.run` fits it and
:func:`silfit.run.write` writes the output folder into ``--out`` atomically (a failed run
leaves no half-written output), its parts chosen by the frames and views (:mod:`silfit.outputs.write`): the one
image's folder of :mod:`silfit.fitting.image_fit`, the rig's of :mod:`silfit.fitting.rig_pipeline`, a video's.
"""

from __future__ import annotations

from pathlib import Path

from . import CLIError, note, warn
from .common import export_formats, save_leaving_nothing_on_error


def _int_list(text: str) -> tuple:
    """An argparse type: raises ``ArgumentTypeError``, which argparse reports as a usage error (exit 2)."""
    import argparse

    try:
        values = tuple(int(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated integers, got {text!r}") from None
    if not values or min(values) <= 0:
        raise argparse.ArgumentTypeError(f"expected positive integers, got {text!r}")
    return values


def _add_input_flags(p) -> None:
    """The keypoints to fit: a rig and its views, a keypoint file and which people."""
    p.add_argument(
        "--rig",
        metavar="DIR",
        help="a calibrated camera rig: cameras.json (or EasyMocap intri.yml + "
        "extri.yml, or one sub-folder per view with camera.json incl. R, t) and per view keypoints.json, "
        "optional mask.png, image.png; fits in world coordinates (see docs/guides/rigs.md)",
    )
    p.add_argument("--views", metavar="A,B", help="--rig: fit only these views (names as in the rig), e.g. cam0,cam2")
    p.add_argument(
        "--keypoints",
        help="OpenPose BODY_25 / COCO-17 keypoint JSON, or OpenPose whole-body JSON (hands "
        "and face: fitted with an SMPL-X-layout model) (default: detected in --image, with its mask unless "
        "--mask is given)",
    )
    p.add_argument("--person", default="largest", help="person index in the keypoint file, or 'largest'")
    p.add_argument(
        "--people",
        metavar="all",
        choices=("all",),
        help="--image without --keypoints: fit every person detected, each into OUT/person_<i>/ "
        "(largest first; OUT/people.json lists them)",
    )


def _add_image_flags(p) -> None:
    """The mask, the camera (a file or a focal length), the image and its size."""
    p.add_argument("--mask", help="person silhouette PNG (enables the silhouette stage)")
    cam = p.add_mutually_exclusive_group()
    cam.add_argument("--camera", help="camera.json with fx, fy, cx, cy, width, height")
    cam.add_argument(
        "--focal",
        type=float,
        help="focal length in pixels (default: max(width, height); with --sequence "
        "it replaces the focal length of a camera.json found beside the frames)",
    )
    p.add_argument(
        "--image",
        help="the image (its size, EXIF focal length and the overlay; keypoints and mask "
        "are detected in it when --keypoints is not given). Its landmark model's 3D decides which way limbs "
        "point in depth where it is confident (the image depth cue; metrics.json's image_depth; "
        "off by default: --keypoint-option image_depth.weight=100 turns it on)",
    )
    p.add_argument("--image-size", help="WxH when neither --camera, --image nor --mask gives the size")


def _add_model_flags(p) -> None:
    """The stages, the body model, the pose prior and the silhouette stage's levels."""
    p.add_argument("--no-silhouette", action="store_true", help="stop after the keypoint stage")
    p.add_argument(
        "--model",
        help="SMPL or SMPL-X model file or folder, or 'open-smplx' for the shipped open whole-body "
        "model (default: the shipped open body model; for keypoints with hands or face the shipped open "
        "whole-body model)",
    )
    p.add_argument("--gender", default="neutral", help="model gender when --model is a folder")
    p.add_argument(
        "--pose-prior",
        help="pose prior: SMPLify gmm_08.pkl, a mixture .npz, or 'limits' (default: the shipped pose-library mixture)",
    )
    p.add_argument(
        "--silhouette-resolutions",
        type=_int_list,
        metavar="R1,R2",
        help="silhouette window sizes per level, coarse to fine (default 128,256)",
    )
    p.add_argument(
        "--silhouette-iterations",
        type=_int_list,
        metavar="N1,N2",
        help="silhouette rendered steps per level (default 30,20, after the contour level)",
    )


def _add_sequence_flags(p) -> None:
    """The video flags, in their own help group."""
    seq = p.add_argument_group("videos (silfit.fitting.sequence)")
    seq.add_argument(
        "--sequence",
        metavar="DIR",
        help="fit a video: a folder of per-frame OpenPose JSON files "
        "(<video>_<frame 12 digits>_keypoints.json, or DIR/keypoints/ or DIR/openpose/ with masks/, images/, "
        "camera.json beside)",
    )
    seq.add_argument("--masks", metavar="DIR", help="--sequence: per-frame masks, matched by frame number")
    seq.add_argument("--images", metavar="DIR", help="--sequence: per-frame images (overlays), matched by frame number")
    seq.add_argument("--meshes", action="store_true", help="--sequence: also write meshes/frame_<n>.obj")
    seq.add_argument("--fps", type=float, default=30.0, help="--sequence: frame rate of overlay.gif (default 30)")
    seq.add_argument("--no-video", action="store_true", help="--sequence: only strip.png, no overlay.gif")
    seq.add_argument("--sequence-iterations", type=int, help="--sequence: joint refinement steps (default 100)")


def _add_result_flags(p) -> None:
    """What is written besides the fit: exported meshes and the depth-branch hypotheses."""
    p.add_argument(
        "--export",
        metavar="glb,ply",
        help="also write mesh.glb / mesh.ply (with --sequence: animation.glb, one "
        "animated glTF of every frame / meshes/frame_<n>.ply): the body upright (x right, y up, z toward the "
        "viewer: the camera frame turned 180 deg about x), vertex normals, the camera in the glTF",
    )
    p.add_argument(
        "--hypotheses",
        type=int,
        default=1,
        metavar="K",
        help="also write the K best distinct keypoint-stage solutions of the limbs' depth branches to "
        "hypotheses/<k>/ (params.npz, mesh.obj; 1: the keypoint stage's best) and hypotheses.png (each "
        "over the image and from the side), their energies and differing segments in metrics.json "
        "(default 1: none); with a mask, each goes through the silhouette stage, hypotheses/<k>/ holds "
        "it refined, and the lowest final energy is kept where it is more than choice_margin (4 %%) below the "
        "keypoint fit's (K times its cost; metrics.json: "
        "hypotheses_silhouette)",
    )


def _add_stage_option_flags(p) -> None:
    """The keypoint and silhouette stages' NAME=VALUE overrides."""
    p.add_argument(
        "--keypoint-option",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="override a KeypointFitConfig field of the keypoint stage (one image, rig, video: each "
        "frame's start), e.g. starts.poses=1 or pose_iters=10,10,10 (repeatable; as fit-dataset)",
    )
    p.add_argument(
        "--silhouette-option",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="override a SilhouetteFitConfig field of the silhouette stage, e.g. alternatives_margin=0 "
        "(without --hypotheses: no close alternative refined against the mask) or plausibility_guard=false "
        "(repeatable; as fit-dataset)",
    )


def _add_run_flags(p) -> None:
    """The output folder and how the run behaves."""
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--overwrite", action="store_true", help="replace an existing output folder")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.add_argument(
        "--check-only",
        action="store_true",
        help="read and check every input (files, sizes, keypoint plausibility), fit and write nothing",
    )


def register(subparsers) -> None:
    p = subparsers.add_parser("fit", help="fit SMPL to an image's 2D keypoints and person mask")
    _add_input_flags(p)
    _add_image_flags(p)
    _add_model_flags(p)
    _add_sequence_flags(p)
    _add_result_flags(p)
    _add_stage_option_flags(p)
    _add_run_flags(p)
    p.set_defaults(func=run)


def run(args) -> int:
    """Build the job (:mod:`silfit.cli.jobs`), check it, fit it (:func:`silfit.run.run`) and
    write its folder (:func:`silfit.run.write`); the same for one image, a rig and a video."""
    from ..run import check, run as run_job, write
    from .jobs import build_job, describe_inputs

    from .common import keypoint_options, silhouette_options

    # a bad option is one line before anything is read; the count of hypotheses is --hypotheses (its checks)
    keypoint_options(args, refused={"hypotheses": "hypotheses", "solutions.count": "hypotheses"})
    silhouette_options(args)
    if getattr(args, "people", None) == "all":
        return _run_people(args)
    exports = export_formats(args)
    job = build_job(args)
    if args.check_only:
        checked = check(job)
        for warning in checked.warnings:
            warn(warning)
        print(describe_inputs(checked))
        return 0
    fit = run_job(job)
    out = Path(args.out)
    save_leaving_nothing_on_error(
        out,
        lambda: write(
            fit,
            out,
            overwrite=args.overwrite,
            exports=exports,
            meshes=args.meshes,
            video=not args.no_video,
            fps=args.fps,
        ),
    )
    print(f"wrote {out}: {fit.summary()}")
    for warning in fit.warnings:
        warn(warning)
    return 0


def _shared_settings(jobs: list) -> list:
    """The people's jobs of one photo with one model, pose prior and settings objects where they are the same
    (built from the same flags, each person's job loaded its own): :func:`silfit.run.run_batch` batches jobs
    that share them, so the people go through each stage together (the same fits bit for bit: a fit does not
    depend on its batch). Jobs whose layout, model file, keypoint or silhouette settings differ keep their own
    (defensive: one photo's detected people have one layout and one model today)."""
    from dataclasses import replace

    out, firsts = [], {}
    for job in jobs:
        key = (
            job.layout,
            getattr(job.model, "source", None) or id(job.model),
            str(getattr(job.model, "dtype", "")),
            getattr(job.model, "kind", None),
        )
        first = firsts.setdefault(key, job)
        if (
            first is not job
            and job.keypoint_config == first.keypoint_config
            and job.silhouette_config == first.silhouette_config
        ):
            job = replace(
                job,
                model=first.model,
                pose_prior=first.pose_prior,
                keypoint_config=first.keypoint_config,
                silhouette_config=first.silhouette_config,
            )
        out.append(job)
    return out


def _run_people(args) -> int:
    """``--people all``: detect every person once, build every person's job (a bad flag or input
    stops here, before anything is written), fit them as one batch (a person that fails is set aside
    with a warning; all failing is an error), then write ``OUT/person_<i>/`` and ``OUT/people.json``
    as one folder (atomic: a failure leaves no output)."""
    import copy
    import json

    if args.keypoints or not args.image:
        raise CLIError("--people all detects the people in --image; give --image and no --keypoints")
    if args.mask:
        raise CLIError("--people all uses each detected person's own mask; drop --mask")
    if args.sequence or getattr(args, "rig", None):
        raise CLIError("--people all is for one photo (--image); not with --sequence or --rig")
    from ..detect import DetectConfig
    from ..detect.output import detect_photo
    from ..outputs.folder import atomic_folder
    from ..run import check, run_batch, write
    from .jobs import build_job, describe_inputs

    exports = export_formats(args)
    out = Path(args.out)
    if out.exists() and not args.overwrite and (not out.is_dir() or any(out.iterdir())):
        raise CLIError(f"{out}: output folder exists and is not empty (use --overwrite)")
    detected = detect_photo(args.image, DetectConfig(max_people=0))
    people = detected[1]
    note(f"{len(people)} person(s) detected in {args.image}")
    jobs = []
    for i in range(len(people)):
        one = copy.copy(args)
        one.people, one.person, one.out, one.detected = None, str(i), str(out / f"person_{i}"), detected
        one.overwrite = True  # OUT itself was checked above; its person_<i>/ are written afresh
        jobs.append(build_job(one))
    jobs = _shared_settings(jobs)
    if args.check_only:
        for i, job in enumerate(jobs):
            checked = check(job)
            for warning in checked.warnings:
                warn(f"person {i}: {warning}")
            print(f"person {i}: {describe_inputs(checked)}")
        return 0
    # one batch through the one path (silfit.run.run_batch): a person whose keypoints are refused or whose fit
    # fails is set aside with a warning (its row in people.json says why), as a rig sets a view aside
    results = run_batch(jobs, isolate=True)
    failed = {i: getattr(r, "error", r) for i, r in enumerate(results) if isinstance(r, Exception)}
    if len(failed) == len(results):
        raise next(iter(failed.values()))
    fits = {i: r for i, r in enumerate(results) if i not in failed}

    def save():
        with atomic_folder(out, args.overwrite) as tmp:
            for i, fit in fits.items():
                write(
                    fit, tmp / f"person_{i}", exports=exports, meshes=args.meshes, video=not args.no_video, fps=args.fps
                )
            rows = [
                {"person": i, "folder": f"person_{i}", "status": "ok"}
                if i in fits
                else {"person": i, "folder": None, "status": "failed", "error": str(failed[i])}
                for i in range(len(results))
            ]
            (tmp / "people.json").write_text(json.dumps({"image": args.image, "people": rows}, indent=2))

    save_leaving_nothing_on_error(out, save)
    for i, fit in fits.items():
        print(f"wrote {out / f'person_{i}'}: {fit.summary()}")
        for warning in fit.warnings:
            warn(f"person {i}: {warning}")
    for i, err in failed.items():
        warn(f"person {i} set aside: {err}")
    return 0
