"""``silfit export-model {smpl,smplx} DIR``: the shipped open models as the ``smplx`` package reads them
(see :mod:`silfit.body.export_model`)."""

from __future__ import annotations


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "export-model",
        help="write the shipped open SMPL / SMPL-X model so smplx.create(DIR, model_type=...) loads it",
        description="Writes DIR/smpl/SMPL_NEUTRAL.pkl or DIR/smplx/SMPLX_NEUTRAL.npz (plain numpy arrays in the smplx "
        "package's layout: hand PCA, face landmarks incl. the contour, 10 shape + 16 expression directions), "
        "vertex_ids.json (the open mesh's vertices for smplx's extra joints) and the licence.",
    )
    p.add_argument(
        "kind", choices=("smpl", "smplx"), help="smpl: the open body model; smplx: the open whole-body model"
    )
    p.add_argument("dir", help="output folder (the model goes into DIR/<kind>/, as smplx.create expects)")
    p.add_argument("--overwrite", action="store_true", help="replace the model in an existing, non-empty DIR/<kind>/")
    p.set_defaults(func=run)


def run(args) -> int:
    from pathlib import Path

    from ..body.export_model import export_model
    from .common import check_out

    check_out(Path(args.dir) / args.kind, args.overwrite)
    for path in export_model(args.kind, args.dir):
        print(f"wrote {path}")
    return 0
