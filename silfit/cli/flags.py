"""One meaning per flag across ``silfit``'s subcommands.

* :data:`MEANINGS`: every flag that more than one subcommand takes, with its one meaning
  (``tests/cli/test_flag_meanings.py`` walks every subcommand's parser: a shared flag missing here, or
  taking values in one subcommand and none in another, fails it).
* :func:`deprecated_alias`: an old spelling of a renamed flag keeps working and says the new one.
* :data:`EXAMPLES`: the examples every subcommand's ``--help`` ends with.
"""

from __future__ import annotations

import argparse
import re
import sys

__all__ = ["MEANINGS", "EXAMPLES", "deprecated_alias", "plain_text", "finish_parser"]

#: Flags several subcommands take, and the one thing each means everywhere.
MEANINGS = {
    "--out": "the output folder (created; `fit-dataset` resumes an existing one)",
    "--quiet": "no progress bars; results, warnings and errors are still printed",
    "--overwrite": "replace an existing, non-empty output folder (without it such a folder is an error)",
    "--model": "the body model: an SMPL / SMPL-X file or folder, or 'open-smplx' (default: the shipped open model)",
    "--camera": "a camera.json (fx, fy, cx, cy, width, height; optional R, t)",
    "--focal": "the focal length in pixels, replacing the camera's or the default one",
    "--gender": "the model file's gender when --model is a folder",
    "--pose-prior": "the pose prior: SMPLify's gmm_08.pkl, a mixture .npz, or 'limits'",
    "--keypoint-option": "NAME=VALUE: a KeypointFitConfig field (repeatable)",
    "--silhouette-option": "NAME=VALUE: a SilhouetteFitConfig field (repeatable)",
    "--silhouette-resolutions": "the silhouette stage's window sizes per level, coarse to fine",
    "--silhouette-iterations": "the silhouette stage's rendered steps per level",
    "--no-silhouette": "the keypoint stage only",
    "--export": "also write these formats of each body (glb, ply)",
    "--images": "per-frame or per-item images (for the overlays), matched by frame number or file stem",
    "--masks": "per-frame or per-item person masks, matched by frame number or file stem",
    "--person": "one person, by its index in the keypoint file (0-based)",
    "--people": "which people: 'all' of them (detect: or up to N; fit-dataset: or the 'largest')",
    "--fps": "frames per second (of a video written or generated)",
    "--size": "the image size in pixels",
    "--whole-body": "SMPL-X-layout subjects with hands and face",
}

#: ``--help`` examples per subcommand.
EXAMPLES = {
    "demo": """\
  silfit demo                             # a shipped synthetic subject: pictures and a table in silfit-demo/
  silfit demo --photo                     # the sample photograph: detect, fit, draw
  silfit demo --photo my.jpg --out demo/  # your own photo
  silfit demo --whole-body                # hands and face close up""",
    "fit": """\
  silfit fit --image photo.jpg --out fit/                          # detect the person, then fit
  silfit fit --image street.jpg --people all --out fits/           # every person detected
  silfit fit --keypoints kp.json --mask mask.png --image image.png --camera camera.json --out fit/
  silfit fit --keypoints kp.json --image image.png --no-silhouette --out fit/   # keypoints only
  silfit fit --keypoints kp.json --image image.png --export glb,ply --out fit/  # + upright mesh.glb, mesh.ply
  silfit fit --rig captures/take_01 --views cam0,cam2 --out fit_rig/            # two cameras of a rig
  silfit fit --sequence openpose_json/ --masks masks/ --out fit_video/          # a video
  silfit fit --keypoints kp.json --image image.png --keypoint-option starts.poses=1 --out fit/""",
    "detect": """\
  silfit detect photo.jpg --out det/                    # keypoints.json (OpenPose BODY_25) + mask.png
  silfit detect street.jpg --people all --out det/      # every person found
  silfit detect photo.jpg --layout coco17 --out det/    # COCO-17 keypoints""",
    "synth": """\
  silfit synth --n 30 --seed 1 --size 512 --noise-px 2 --out data/mine
  silfit synth --poses hard --n 60 --seed 1 --out data/hard         # deep flexion, front and back views
  silfit synth --n 10 --cameras 4 --seed 1 --out data/rigs          # a calibrated 4-camera rig per subject
  silfit synth --videos --n 10 --frames 60 --seed 1 --out data/motions   # walk, run, squat, wave, turn
  silfit synth --whole-body --n 4 --out data/wb                     # hands and face""",
    "eval": """\
  silfit eval data/mine --run --report report.json   # fit every subject, keypoints only vs + silhouette
  silfit eval data/mine --fits fits/ --report r.json # score fits made before""",
    "render": """\
  silfit render fit/params.npz --directions front,side,back --out views/
  silfit render fit/mesh.obj --turntable 8 --out turn/
  silfit render fit/params.npz --overlay image.png --camera camera.json --write-mask --out overlay/
  silfit render fit_video/params.npz --frame all --directions side --out side_gif/""",
    "fit-dataset": """\
  silfit fit-dataset openpose_out/ --masks masks/ --images frames/ --camera camera.json --people all --out fits/
  silfit fit-dataset rows.jsonl --out fits/ --batch-size 32 --no-silhouette
  silfit fit-dataset data/synthetic --out fits/ --workers auto     # one process per CPU
  silfit fit-dataset data/synthetic --out fits/ --ray              # on a local Ray
  silfit fit-dataset rows.csv --out fits/ --retry-failed           # resume, and retry what failed""",
    "export-model": """\
  silfit export-model smplx models/   # models/smplx/SMPLX_NEUTRAL.npz: smplx.create("models", model_type="smplx")
  silfit export-model smpl models/    # models/smpl/SMPL_NEUTRAL.pkl""",
    "report": """\
  silfit report fits/                    # fits/report/index.html: a sortable gallery, opens with no server
  silfit report fits/ --no-side-views    # faster for thousands of fits""",
}


class _Deprecated(argparse.Action):
    """An old spelling: says the new one on standard error, then does what the new one does."""

    def __init__(self, option_strings, dest, target: argparse.Action = None, new: str = "", **kwargs):
        super().__init__(option_strings, dest, **kwargs)
        self.target, self.new = target, new

    def __call__(self, parser, namespace, values, option_string=None):
        print(f"warning: {option_string} is deprecated, use {self.new} (same meaning)", file=sys.stderr)
        self.target(parser, namespace, values, self.new)


def deprecated_alias(parser: argparse.ArgumentParser, old: str, new: str) -> None:
    """Accept ``old`` as a hidden, deprecated spelling of ``parser``'s flag ``new``."""
    target = next(a for a in parser._actions if new in a.option_strings)
    parser.add_argument(
        old,
        action=_Deprecated,
        target=target,
        new=new,
        dest=target.dest,
        nargs=target.nargs,
        type=target.type,
        choices=target.choices,
        metavar=target.metavar,
        default=argparse.SUPPRESS,
        help=argparse.SUPPRESS,
    )


def is_deprecated(action: argparse.Action) -> bool:
    return isinstance(action, _Deprecated)


_ROLE = re.compile(r":(?:mod|func|class|meth|attr|data):`~?([^`]+)`")


def plain_text(text: str) -> str:
    """Docstring markup (``:mod:`x```, double backquotes) as the plain text a terminal shows."""
    return _ROLE.sub(r"\1", text or "").replace("``", "")


def finish_parser(name: str, parser: argparse.ArgumentParser) -> None:
    """Plain-text description, and the subcommand's examples at the end of its ``--help``."""
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    if parser.description:
        parser.description = plain_text(parser.description)
    examples = EXAMPLES.get(name)
    if examples:
        epilog = plain_text(parser.epilog) + "\n\n" if parser.epilog else ""
        parser.epilog = f"{epilog}examples:\n{examples}"
