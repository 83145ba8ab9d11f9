"""Interpenetration term: energy on contact / intersecting / library poses, and its cost.

    python benchmarks/bench_interpenetration.py                 # the current SphereCollisionModel
    git show cea32f3:silfit/priors/interpenetration.py > /tmp/old_interp.py
    python benchmarks/bench_interpenetration.py --module /tmp/old_interp.py   # another implementation

Prints, per pose, the mesh's contact (gap, depth of the deepest vertex inside the other
part) and the term's energy in fitter units (x 1e5, the keypoint stage's weight), then
the build time and the forward+backward time for a batch of 32 (median of 30 runs;
timings on a shared CPU are noisy).
"""

from __future__ import annotations

import argparse
import importlib.util
import time

import silfit  # noqa: F401  (first: the CPU kernels are pinned before numpy and torch load, silfit.kernels)
import numpy as np
import torch


def load_class(path):
    if path is None:
        from silfit.priors.interpenetration import SphereCollisionModel

        return SphereCollisionModel
    spec = importlib.util.spec_from_file_location("other_interpenetration", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod.SphereCollisionModel


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--module", default=None, help="a file defining SphereCollisionModel (default: silfit's)")
    ap.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)

    import silfit
    from silfit.fitting.body import body_transforms
    from silfit.poses.contact import contact_examples, intersecting_examples, part_contact, posed_vertices
    from silfit.poses.library import POSE_LIBRARY

    model = silfit.load_body_model()
    cls = load_class(args.module)
    t = time.perf_counter()
    col = cls(model)
    build = time.perf_counter() - t

    rows = [(f"contact: {n}", p, pairs) for n, (p, pairs) in contact_examples(model).items()]
    rows += [(f"intersecting: {n}", p, pairs) for n, (p, pairs) in intersecting_examples().items()]
    rows += [
        (f"library: {n}", POSE_LIBRARY[n].body_pose, None)
        for n in ("stand_relaxed", "sit_chair", "squat_deep", "kneel_one", "phone_call")
    ]
    print("| pose | gap (cm) | depth (cm) | energy x 1e5 |")
    print("|---|---:|---:|---:|")
    for name, pose, pairs in rows:
        p = torch.as_tensor(pose, dtype=torch.float32)[None]
        z = torch.zeros(1, model.num_betas)
        e = float(col(z, body_transforms(model, z, torch.zeros(1, 3), p))) * 1e5
        if pairs:
            v = posed_vertices(model, pose)
            c = [part_contact(model, v, a, b) for a, b in pairs]
            gap, depth = f"{min(x.gap for x in c) * 100:.2f}", f"{max(x.depth for x in c) * 100:.2f}"
        else:
            gap = depth = "-"
        print(f"| {name} | {gap} | {depth} | {e:.2f} |")

    names = list(POSE_LIBRARY)
    P = torch.tensor(np.stack([POSE_LIBRARY[names[i % len(names)]].body_pose for i in range(32)]), dtype=torch.float32)
    betas = torch.randn(32, model.num_betas, generator=torch.Generator().manual_seed(0)) * 0.5
    T0 = body_transforms(model, betas, torch.zeros(32, 3), P).detach()
    times = []
    for _ in range(30):
        b, T = betas.clone().requires_grad_(True), T0.clone().requires_grad_(True)
        t = time.perf_counter()
        col(b, T).sum().backward()
        times.append(time.perf_counter() - t)
    print(
        f"\nspheres {col.num_spheres}, tested pairs {len(col.pair_a)}, build {build:.2f} s, "
        f"forward+backward batch 32: median {np.median(times) * 1e3:.1f} ms (min {min(times) * 1e3:.1f}), {args.threads} thread(s)"
    )


if __name__ == "__main__":
    main()
