"""``silfit synth``: generate synthetic subjects with known ground truth."""

from __future__ import annotations

import argparse
import shlex
import sys


def _add_dataset_flags(p) -> None:
    """How many subjects, where, the seed, the image size and the keypoints' noise, drops and truncation."""
    p.add_argument("--n", type=int, required=True, help="number of subjects")
    p.add_argument("--out", required=True, help="output dataset folder")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--size", type=int, default=512, help="image width = height in pixels (default 512)")
    p.add_argument("--noise-px", type=float, default=2.0, help="keypoint noise std. dev. in pixels (default 2)")
    p.add_argument(
        "--clean", type=int, default=0, help="the first CLEAN subjects get no noise and no dropped keypoints"
    )
    p.add_argument("--drop", type=float, default=0.0, help="probability of dropping each keypoint (default 0)")
    p.add_argument("--truncation", type=float, default=0.0, help="probability of a partly truncated body (default 0)")


def _add_view_flags(p) -> None:
    """The ranges of the camera's field of view, framing, elevation and roll, the body's yaw and pose perturbation."""
    p.add_argument(
        "--fov", type=float, nargs=2, default=(45.0, 65.0), metavar=("MIN", "MAX"), help="field of view range, degrees"
    )
    p.add_argument(
        "--fill",
        type=float,
        nargs=2,
        default=(0.55, 0.85),
        metavar=("MIN", "MAX"),
        help="share of the frame the body's box fills (default 0.55 0.85)",
    )
    p.add_argument("--elevation", type=float, default=15.0, help="camera elevation range +-degrees (default 15)")
    p.add_argument(
        "--yaw",
        type=float,
        nargs=2,
        default=(-180.0, 180.0),
        metavar=("MIN", "MAX"),
        help="body yaw range, degrees (0 = facing the camera; default -180 180)",
    )
    p.add_argument("--roll", type=float, default=5.0, help="camera roll range +-degrees (default 5)")
    p.add_argument("--perturb", type=float, default=6.0, help="pose perturbation std. dev., degrees (default 6)")


def _add_subject_flags(p) -> None:
    """The background, the COCO-17 keypoints, whole-body subjects and where the poses come from."""
    p.add_argument("--background", choices=("plain", "textured", "mixed"), default="mixed")
    p.add_argument("--coco", action="store_true", help="also write keypoints_coco17.json")
    p.add_argument(
        "--whole-body",
        action="store_true",
        help="SMPL-X-layout subjects (default model: the shipped open whole-body model) with library hand "
        "poses, expressions and OpenPose whole-body keypoints (body, hands, face) in keypoints.json",
    )
    p.add_argument(
        "--poses",
        choices=("library", "hard"),
        default="library",
        help="library: around the hand-authored pose library (default); hard: silfit.poses.sampler's squats, "
        "kneeling, running, lunges, hands at the face/head/hip, front and back views over-represented",
    )


def _add_video_flags(p) -> None:
    """Short motions instead of single images (--videos) and their settings."""
    p.add_argument(
        "--videos",
        dest="sequence",
        action="store_true",
        help="--n short motions instead of single images (silfit.synth.motion: walk, run, squat, wave, turn; "
        "per-frame OpenPose JSON, masks, images and per-frame truth in one folder per sequence)",
    )
    p.add_argument("--frames", type=int, default=60, help="--videos: frames per sequence (default 60)")
    p.add_argument("--fps", type=float, default=30.0, help="--videos: frame rate (default 30)")
    p.add_argument("--motions", default=None, help="--videos: comma-separated motions, cycled (default: all)")
    p.add_argument("--orbit", type=float, default=0.0, help="--videos: camera orbit over the clip, degrees (default 0)")
    p.add_argument(
        "--drop-frames",
        type=float,
        default=0.0,
        help="--videos: probability of a frame with no person detected (default 0)",
    )


def _add_rig_flags(p) -> None:
    """A calibrated camera rig per subject: a ring of N cameras or a cameras.json."""
    p.add_argument(
        "--cameras",
        dest="views",
        type=int,
        default=None,
        metavar="N",
        help="a calibrated rig per subject: N cameras on a ring around the body (varied heights), per-view "
        "folders view_<i>/ (image, mask, keypoints, camera.json with R, t), cameras.json and one gt.npz "
        "in world coordinates (see docs/guides/rigs.md); with --whole-body, OpenPose whole-body "
        "keypoints per view; with --videos, each motion seen by N cameras (a rig video: per-view "
        "video folders)",
    )
    p.add_argument(
        "--cameras-file",
        dest="layout",
        default=None,
        metavar="CAMERAS.json",
        help="with --cameras: the rig's cameras from this cameras.json instead of the ring",
    )


def _add_run_flags(p) -> None:
    """The body model, the progress bar and writing into an existing folder."""
    p.add_argument("--model", default=None, help="body model file (default: the shipped open body model)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--overwrite", action="store_true", help="write into an existing, non-empty output folder")


def _add_deprecated_aliases(p) -> None:
    """The old spellings of renamed flags (hidden; they say the new one)."""
    from .flags import deprecated_alias

    for old, new in (
        ("--sequence", "--videos"),
        ("--views", "--cameras"),
        ("--layout", "--cameras-file"),
        ("--no-progress", "--quiet"),
    ):
        deprecated_alias(p, old, new)


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "synth",
        help="generate synthetic subjects (image, mask, keypoints, camera, ground truth)",
        description=(
            "Render random people (hand-authored pose library, shape prior, random cameras) and write one "
            "folder per subject: image.png, mask.png, keypoints.json (OpenPose BODY_25), camera.json, gt.npz; "
            "plus index.json with the settings. Deterministic for a given --seed."
        ),
    )
    _add_dataset_flags(p)
    _add_view_flags(p)
    _add_subject_flags(p)
    _add_video_flags(p)
    _add_rig_flags(p)
    _add_run_flags(p)
    _add_deprecated_aliases(p)
    p.set_defaults(func=run)


def run_sequence(args: argparse.Namespace, model) -> int:
    from ..synth.motion import MOTIONS, SequenceConfig, generate_sequence_dataset

    motions = tuple(m.strip() for m in args.motions.split(",") if m.strip()) if args.motions else tuple(MOTIONS)
    cfg = SequenceConfig(
        seed=args.seed,
        frames=args.frames,
        fps=args.fps,
        size=args.size,
        noise_px=args.noise_px,
        drop_prob=args.drop,
        drop_frames=args.drop_frames,
        motions=motions,
        orbit_deg=args.orbit,
        fov_deg=tuple(args.fov),
        background=args.background,
    ).validate()
    index = generate_sequence_dataset(
        args.out,
        args.n,
        cfg,
        model=model,
        progress=not args.quiet,
        command=shlex.join(["silfit", "synth", *sys.argv[2:]]),
        views=args.views,
    )
    seqs = index["sequences"]
    rig = f" seen by {args.views} cameras" if args.views else ""
    print(
        f"wrote {len(seqs)} sequences of {args.frames} frames{rig} to {args.out} (seed {args.seed}, {args.size}x{args.size}, "
        f"noise {args.noise_px} px): {', '.join(s['name'] + ' ' + s['motion'] for s in seqs)}"
    )
    return 0


def _body_model(args):
    """``--model``'s body model, or ``None`` (the generator's default: the shipped open model)."""
    model = None
    if args.model is not None:
        from ..body import load_body_model

        model = load_body_model(args.model)
    return model


def _synth_config(args: argparse.Namespace):
    """The single-image subjects' :class:`silfit.synth.generate.SynthConfig` (validated) from the flags."""
    from ..synth.generate import SynthConfig

    return SynthConfig(
        seed=args.seed,
        size=args.size,
        noise_px=args.noise_px,
        clean=args.clean,
        drop_prob=args.drop,
        truncation_prob=args.truncation,
        fov_deg=tuple(args.fov),
        fill=tuple(args.fill),
        elevation_deg=args.elevation,
        roll_deg=args.roll,
        perturb_deg=args.perturb,
        yaw_range_deg=tuple(args.yaw),
        background=args.background,
        coco=args.coco,
        whole_body=args.whole_body,
        poses=args.poses,
        frontal_first=args.poses == "library",
    ).validate()


def _command_argv(args: argparse.Namespace) -> list:
    """The command that regenerates the dataset, as recorded in index.json: the output folder as DIR and only
    the flags that differ from their defaults (a rig adds its own, :func:`_run_rig`)."""
    argv = [
        "silfit",
        "synth",
        "--n",
        str(args.n),
        "--seed",
        str(args.seed),
        "--out",
        "DIR",
        "--size",
        str(args.size),
        "--noise-px",
        str(args.noise_px),
    ] + (["--clean", str(args.clean)] if args.clean else [])
    for flag, value, default in (
        ("--drop", args.drop, 0.0),
        ("--truncation", args.truncation, 0.0),
        ("--elevation", args.elevation, 15.0),
        ("--roll", args.roll, 5.0),
        ("--perturb", args.perturb, 6.0),
        ("--background", args.background, "mixed"),
    ):
        if value != default:
            argv += [flag, str(value)]
    if tuple(args.fov) != (45.0, 65.0):
        argv += ["--fov", *map(str, args.fov)]
    if tuple(args.fill) != (0.55, 0.85):
        argv += ["--fill", *map(str, args.fill)]
    if tuple(args.yaw) != (-180.0, 180.0):
        argv += ["--yaw", *map(str, args.yaw)]
    if args.coco:
        argv.append("--coco")
    if args.whole_body:
        argv.append("--whole-body")
    if args.poses != "library":
        argv += ["--poses", args.poses]
    return argv


def _print_summary(args: argparse.Namespace, index: dict) -> None:
    """Two lines on the written dataset: how many subjects, and the ranges of stature, distance and yaw."""
    from ..synth.generate import dataset_summary

    s = dataset_summary(index)
    print(
        f"wrote {len(index['subjects'])} subjects to {args.out} (seed {args.seed}, {args.size}x{args.size}, noise {args.noise_px} px)"
    )
    print(
        f"stature {s['stature_m']['min']:.2f}-{s['stature_m']['max']:.2f} m (median {s['stature_m']['median']:.2f}); "
        f"distance {s['distance_m']['min']:.2f}-{s['distance_m']['max']:.2f} m (median {s['distance_m']['median']:.2f}); "
        f"yaw {s['yaw_deg']['min']:.0f}..{s['yaw_deg']['max']:.0f} deg, {s['back_facing']} back-facing; "
        f"{s['truncated']} truncated"
    )


def run(args: argparse.Namespace) -> int:
    from .common import check_out

    check_out(args.out, args.overwrite)
    if args.sequence and args.layout is not None:
        raise ValueError("--videos with --cameras-file: rig videos place their cameras on a ring (--cameras N)")
    if args.sequence:
        return run_sequence(args, _body_model(args))
    from ..synth.generate import generate_dataset

    cfg = _synth_config(args)
    model = _body_model(args)
    argv = _command_argv(args)
    if args.views is not None or args.layout is not None:
        return _run_rig(args, cfg, model, argv)
    index = generate_dataset(args.out, args.n, cfg, model=model, progress=not args.quiet, command=shlex.join(argv))
    _print_summary(args, index)
    return 0


def _run_rig(args, cfg, model, argv) -> int:
    from ..io.rig import read_cameras_json
    from ..synth.camera_rigs import RigConfig, generate_rig_dataset

    if args.poses != "library":
        raise ValueError("--cameras: rigs use the library poses (no --poses hard)")
    layout = [v.view for v in read_cameras_json(args.layout)] if args.layout else None
    rig = RigConfig(views=args.views if args.views is not None else (len(layout) if layout else 4), layout=layout)
    argv += ["--cameras", str(rig.views)] + (["--cameras-file", args.layout] if args.layout else [])
    index = generate_rig_dataset(
        args.out, args.n, cfg, rig, model=model, progress=not args.quiet, command=shlex.join(argv)
    )
    print(
        f"wrote {len(index['subjects'])} rig subjects ({index['rig']} views each) to {args.out} (seed {args.seed}, "
        f"{args.size}x{args.size}, noise {args.noise_px} px)"
    )
    return 0
