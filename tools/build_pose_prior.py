"""Rebuild silfit's default pose prior, ``silfit/priors/data/pose_mixture.npz``.

A Gaussian mixture (SMPLify's best-component form) fitted to samples around silfit's
hand-authored pose library; see :mod:`silfit.priors.library_prior` for the sampling,
the fit and why results on silfit's synthetic data overstate its value on real photos.
Deterministic: the same settings give the same file.

    python tools/build_pose_prior.py                       # the shipped file
    python tools/build_pose_prior.py --out /tmp/half.npz --names-half a   # held-out build
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import silfit  # noqa: E402, F401  (first: the CPU kernels are pinned before numpy and torch load, silfit.kernels)
import numpy as np  # noqa: E402

from silfit.io.subjects import save_npz  # noqa: E402
from silfit.priors.library_prior import BUILD_DEFAULTS, build_library_mixture, split_library  # noqa: E402


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, default=ROOT / "silfit" / "priors" / "data" / "pose_mixture.npz")
    ap.add_argument("--names", nargs="*", help="library pose names to build from (default: all)")
    ap.add_argument("--names-half", choices=("a", "b"), help="build from one half of split_library(--split-seed)")
    ap.add_argument("--split-seed", type=int, default=0)
    for k, v in BUILD_DEFAULTS.items():
        ap.add_argument("--" + k.replace("_", "-"), type=type(v), default=v)
    args = ap.parse_args(argv)
    names = args.names or None
    if args.names_half:
        names = split_library(args.split_seed)[0 if args.names_half == "a" else 1]
    settings = {k: getattr(args, k) for k in BUILD_DEFAULTS}
    data = build_library_mixture(names, **settings)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    # Deterministic (fixed zip timestamps) and atomic: the same settings give the same bytes.
    save_npz(
        args.out, {k: (v.astype(np.float32) if k in ("means", "covars", "weights") else v) for k, v in data.items()}
    )
    print(
        f"wrote {args.out} ({args.out.stat().st_size / 1024:.0f} KiB): {data['means'].shape[0]} components, "
        f"{len(data['pose_names'])} library poses, mean log-likelihood {float(data['loglik']):.2f}"
    )


if __name__ == "__main__":
    main()
