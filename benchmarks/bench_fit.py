"""Benchmark of the fitting stages on synthetic subjects; prints Markdown tables.

Sets: the shipped synthetic set (``data/synthetic/<subject>/``, if present) and a set
generated here: the open body model in random poses inside the joint limits (arms
lowered at random, limbs bent), betas ~ N(0, 0.5^2), yaw uniform over all 360 degrees,
keypoints (BODY_25) projected with a 512x512 default camera plus 2 px Gaussian noise.

Metrics per method: median reprojection error (px, against the given keypoints), MPJPE
and PVE after pelvis alignment, PA-MPJPE (similarity Procrustes), facing correct (the
fitted body-forward vector within 90 degrees of the true one, in the ground plane),
seconds per image fitted one by one and in batches of ``--batch``.

More sets: ``--synth N`` generates N subjects with silfit's own synthetic generator
(:func:`silfit.synth.generate_dataset`, poses from the pose library, seed ``--seed``);
``--holdout N`` is the held-out check of the default pose prior: a mixture built from
one half of the pose library (:func:`silfit.priors.library_prior.split_library`) is
compared on N subjects posed only from the *other* half (mirrored, perturbed, not
blended; random yaw, elevation, shape and camera as in the generator).

``--prior`` picks the pose prior(s) compared (``default``: the shipped library mixture,
``limits``: the data-free split normal, or a mixture file); ``--set key=value`` overrides
a :class:`~silfit.fitting.KeypointFitConfig` field (lists comma-separated).

**Circularity.** The shipped and ``--synth`` sets are posed from the same library the
default prior is built from, so the default prior's numbers on them are optimistic;
the generated (random poses) and ``--holdout`` sets are the fairer checks.

**Silhouette stage.** ``--silhouette N`` generates N subjects with silfit's generator
(images, masks, keypoints with ``--noise`` px noise, all yaws; ``--size`` pixels) and runs
both methods through the evaluator (:func:`silfit.eval.evaluate.evaluate_dataset`):
keypoint-only (batched) vs keypoint + silhouette (per subject, starting from the
keypoint fit). It prints mean/median IoU, PVE, shape-only PVE, PA-MPJPE and seconds per
stage, and the relative change against the issue's targets.

    python benchmarks/bench_fit.py --subjects 50 --singles 5
    python benchmarks/bench_fit.py --subjects 0 --no-shipped --silhouette 30 --seed 1
    python benchmarks/bench_fit.py --subjects 20 --synth 24 --holdout 24 --prior default --prior limits
    python benchmarks/bench_fit.py --subjects 0 --no-shipped --hard 60 --seed 101      # the hard set (issue 9's table)
    python benchmarks/bench_fit.py --subjects 0 --no-shipped --silhouette-batches 1,8,16
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import silfit  # noqa: F401  (first: the CPU kernels are pinned before numpy and torch load, silfit.kernels)
import numpy as np
import torch
from scipy.spatial.transform import Rotation

from silfit import load_body_model
from silfit.camera import Camera, load_camera, project_points
from silfit.fitting import KeypointFitter
from silfit.io.keypoints import model_keypoints, read_keypoints
from silfit.priors import clamp_to_limits
from silfit.fitting.silhouette_stage import Rendering

ROOT = Path(__file__).resolve().parents[1]


def generate(model, n, seed=0, noise_px=2.0, size=512):
    g = torch.Generator().manual_seed(seed)
    pose = torch.randn(n, 69, generator=g) * 0.2
    # Arms lowered by a random amount, elbows and knees bent the natural way.
    pose[:, 3 * 15 + 2] += -1.3 * torch.rand(n, generator=g)  # left shoulder z
    pose[:, 3 * 16 + 2] += 1.3 * torch.rand(n, generator=g)  # right shoulder z
    pose[:, 3 * 17 + 1] += -1.2 * torch.rand(n, generator=g)  # left elbow y
    pose[:, 3 * 18 + 1] += 1.2 * torch.rand(n, generator=g)  # right elbow y
    pose[:, 3 * 3] += 0.8 * torch.rand(n, generator=g)  # knees
    pose[:, 3 * 4] += 0.8 * torch.rand(n, generator=g)
    pose[:, 0] -= 0.5 * torch.rand(n, generator=g)  # hips flexed
    pose[:, 3] -= 0.5 * torch.rand(n, generator=g)
    pose[:, 57:69] *= 0.3  # wrists and hands (SMPL joints 20-23): small
    pose = clamp_to_limits(pose)
    yaw = torch.rand(n, generator=g).numpy() * 2 * math.pi
    orient = np.stack(
        [(Rotation.from_rotvec([math.pi, 0, 0]) * Rotation.from_rotvec([0, y, 0])).as_rotvec() for y in yaw]
    )
    betas = torch.randn(n, 10, generator=g) * 0.5
    transl = torch.stack(
        [torch.rand(n, generator=g) * 0.4 - 0.2, torch.rand(n, generator=g) * 0.2, 3.0 + torch.rand(n, generator=g)], 1
    )
    gt = dict(betas=betas, body_pose=pose, global_orient=torch.tensor(orient, dtype=torch.float32), transl=transl)
    with torch.no_grad():
        out = model(**gt)
        cam = Camera.from_image_size(size, size)
        xy = project_points(model_keypoints(model, out, "body25"), cam)
    xy = xy + noise_px * torch.randn(xy.shape, generator=g)
    kps = [np.concatenate([xy[i].numpy(), np.ones((25, 1))], 1) for i in range(n)]
    return dict(
        keypoints=kps, cameras=[cam] * n, joints=out.joints.numpy(), vertices=out.vertices.numpy(), global_orient=orient
    )


def load_shipped():
    return load_dir(ROOT / "data" / "synthetic")


def load_dir(root):
    subjects = sorted(p.parent for p in Path(root).glob("*/gt.npz"))
    if not subjects:
        return None
    kps, cams, joints, verts, orients = [], [], [], [], []
    for d in subjects:
        ks = read_keypoints(d / "keypoints.json")
        kps.append(ks.as_array())
        cams.append(load_camera(d / "camera.json"))
        gt = np.load(d / "gt.npz")
        joints.append(gt["joints"].reshape(-1, 24, 3)[0])
        verts.append(gt["vertices"].reshape(1, -1, 3)[0])
        orients.append(gt["global_orient"].reshape(-1)[:3])
    return dict(
        keypoints=kps,
        cameras=cams,
        joints=np.stack(joints),
        vertices=np.stack(verts),
        global_orient=np.stack(orients),
        names=[d.name for d in subjects],
    )


def generate_synth(model, n, seed, noise_px, size=256):
    import tempfile

    from silfit.synth import generate_dataset
    from silfit.synth.generate import SynthConfig

    with tempfile.TemporaryDirectory() as tmp:
        generate_dataset(tmp, n, SynthConfig(seed=seed, size=size, noise_px=noise_px), model=model)
        return load_dir(tmp)


def generate_holdout(model, n, names, seed=0, noise_px=2.0, size=512):
    """Subjects posed only from the library poses ``names`` (no blending)."""
    from silfit.synth.sampler import global_orientation, place_body, sample_betas, sample_intrinsics, sample_pose

    rng = np.random.default_rng([seed, 7])
    kps, cams, joints, verts, orients = [], [], [], [], []
    for _ in range(n):
        ps = sample_pose(rng, names=names, perturb_deg=6.0, blend_prob=0.0, mirror_prob=0.5)
        orient = global_orientation(rng.uniform(-180, 180), rng.uniform(-15, 15), rng.uniform(-5, 5), root=ps.root)
        cam, _ = sample_intrinsics(rng, size, size)
        p = dict(
            betas=torch.as_tensor(sample_betas(rng, model.num_betas))[None],
            body_pose=torch.as_tensor(ps.body_pose)[None],
            global_orient=torch.as_tensor(orient)[None],
        )
        p = {k: v.to(model.dtype) for k, v in p.items()}
        with torch.no_grad():
            place = place_body(rng, model(**p).vertices[0].double().numpy(), cam)
            p["transl"] = torch.as_tensor(place.transl, dtype=model.dtype)[None]
            out = model(**p)
            xy = project_points(model_keypoints(model, out, "body25"), cam)[0].numpy()
        xy = xy + rng.normal(0.0, noise_px, xy.shape)
        kps.append(np.concatenate([xy, np.ones((25, 1))], 1))
        cams.append(cam)
        joints.append(out.joints[0].numpy())
        verts.append(out.vertices[0].numpy())
        orients.append(orient)
    return dict(
        keypoints=kps, cameras=cams, joints=np.stack(joints), vertices=np.stack(verts), global_orient=np.stack(orients)
    )


def procrustes_error(X, Y):
    X0, Y0 = X - X.mean(0), Y - Y.mean(0)
    U, S, Vt = np.linalg.svd(X0.T @ Y0)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    s = (S * np.diag(D)).sum() / (X0**2).sum()
    return float(np.linalg.norm(s * X0 @ (U @ D @ Vt) - Y0, axis=1).mean())


def metrics(res, data):
    n = len(res)
    out = {k: [] for k in ("reproj", "mpjpe", "pa", "pve", "facing")}
    for i in range(n):
        J, Jg = res.joints[i], data["joints"][i]
        out["reproj"].append(float(res.reprojection_error[i]))
        out["mpjpe"].append(float(np.linalg.norm((J - J[0]) - (Jg - Jg[0]), axis=1).mean()))
        out["pa"].append(procrustes_error(J, Jg))
        V, Vg = res.vertices[i], data["vertices"][i]
        out["pve"].append(float(np.linalg.norm((V - J[0]) - (Vg - Jg[0]), axis=1).mean()))
        f = Rotation.from_rotvec(res.global_orient[i].astype(np.float64)).apply([0, 0, 1.0])
        fg = Rotation.from_rotvec(np.asarray(data["global_orient"][i], np.float64)).apply([0, 0, 1.0])
        out["facing"].append(float(f[0] * fg[0] + f[2] * fg[2] > 0))
    return out


def run_set(name, data, fitter, batch, singles):
    n = len(data["keypoints"])
    t0 = time.perf_counter()
    parts = []
    for s in range(0, n, batch):
        parts.append(
            fitter.fit(np.stack(data["keypoints"][s : s + batch]), data["cameras"][s : s + batch], progress=False)
        )
    t_batch = (time.perf_counter() - t0) / n
    m = {k: [] for k in ("reproj", "mpjpe", "pa", "pve", "facing")}
    for k, r in enumerate(parts):
        sub = {key: (v[k * batch : k * batch + len(r)] if key != "cameras" else None) for key, v in data.items()}
        for key, vals in metrics(r, sub).items():
            m[key] += vals
    t_single = []
    for i in range(min(singles, n)):
        t = time.perf_counter()
        fitter.fit(data["keypoints"][i], data["cameras"][i], progress=False)
        t_single.append(time.perf_counter() - t)
    return m, (float(np.mean(t_single)) if t_single else float("nan")), t_batch


def parse_set(items):
    from dataclasses import fields

    from silfit.fitting import KeypointFitConfig

    types = {f.name: f.type for f in fields(KeypointFitConfig)}
    out = {}
    for item in items:
        k, _, v = item.partition("=")
        if k not in types:
            raise SystemExit(f"--set: unknown KeypointFitConfig field {k!r}")
        vals = [float(x) if "." in x or "e" in x else int(x) for x in v.split(",")]
        out[k] = tuple(vals) if ("Sequence" in str(types[k]) or len(vals) > 1) else vals[0]
    return out


SILHOUETTE_TARGETS = (  # (metric, label, target relative change or absolute floor)
    ("iou", "mean IoU after refinement >= 0.93", 0.93),
    ("pve", "PVE >= 20 % lower", -0.20),
    ("shape_pve", "shape-only PVE >= 30 % lower", -0.30),
    ("shape_pve_scaled", "(for reference) shape-only PVE, stature aligned", -0.30),
)


def run_silhouette_benchmark(model, n, seed, noise_px, size, keep=None):
    """Keypoint-only vs keypoint + silhouette on a fresh synthetic set (see the docstring)."""
    import tempfile

    from silfit.eval.evaluate import evaluate_dataset, markdown_table
    from silfit.synth import generate_dataset
    from silfit.synth.generate import SynthConfig

    with tempfile.TemporaryDirectory() as tmp:
        root = Path(keep or tmp)
        t0 = time.perf_counter()
        generate_dataset(root, n, SynthConfig(seed=seed, size=size, noise_px=noise_px), model=model, progress=True)
        print(
            f"generated {n} subjects ({size}x{size}, {noise_px:g} px noise, seed {seed}) in {time.perf_counter() - t0:.0f} s\n"
        )
        report = evaluate_dataset(root, model=model, run=True, methods=("keypoints", "silhouette"))
    print(markdown_table(report))
    summary = report["summary"]
    kp, sil = summary.get("keypoints", {}), summary.get("silhouette", {})
    print("\n| target | keypoints | keypoints + silhouette | change | met |")
    print("|---|---:|---:|---:|---|")
    for key, label, target in SILHOUETTE_TARGETS:
        if key not in kp or key not in sil:
            continue
        a, b = kp[key]["mean"], sil[key]["mean"]
        change = (b - a) / a
        met = b >= target if key == "iou" else change <= target
        print(f"| {label} | {a:.3f} | {b:.3f} | {100 * change:+.1f} % | {'yes' if met else 'no'} |")
    if "time_silhouette" in sil:
        t = sil["time_silhouette"]["mean"]
        print(f"| silhouette stage < 10 s per subject | - | {t:.1f} s | - | {'yes' if t < 10 else 'no'} |")
    if report.get("skipped"):
        print(f"\nskipped: {report['skipped']}")
    return report


def silhouette_timing(model, batches, n=16, seed=11, size=512, config=None):
    """Seconds per subject of the silhouette stage run alone (batch 1) and in batches."""
    import tempfile

    from silfit.io.subjects import list_subjects, load_subject
    from silfit.fitting.silhouette_stage import SilhouetteFitConfig, fit_silhouettes
    from silfit.synth import generate_dataset
    from silfit.synth.generate import SynthConfig

    with tempfile.TemporaryDirectory() as tmp:
        generate_dataset(tmp, n, SynthConfig(seed=seed, size=size, noise_px=2.0), model=model)
        subjects = [load_subject(p) for p in list_subjects(tmp)]
    fitter = KeypointFitter(model)
    kp = fitter.fit([s.keypoints for s in subjects], [s.camera for s in subjects], progress=False)
    print(f"\nsilhouette stage timing ({n} subjects {size}x{size}, seed {seed})\n")
    print("| batch | s/subject | mean IoU (window) | steps/subject |")
    print("|---:|---:|---:|---:|")
    for b in batches:
        t0 = time.perf_counter()
        res = []
        for i in range(0, n, b):
            chunk = list(range(i, min(n, i + b)))
            res += fit_silhouettes(
                model,
                [kp.params(j) for j in chunk],
                [subjects[j].camera for j in chunk],
                [subjects[j].mask for j in chunk],
                [subjects[j].keypoints.as_array() for j in chunk],
                config=config or SilhouetteFitConfig(),
                pose_prior=fitter.pose_prior,
                progress=False,
            )
        dt = (time.perf_counter() - t0) / n
        print(
            f"| {b} | {dt:.2f} | {np.mean([r.iou_end for r in res]):.3f} | {np.mean([r.steps for r in res]):.0f} |",
            flush=True,
        )


def depth_branch_table(report, label):
    """The limb-branch table (issue targets): PA-PVE / PA-MPJPE mean, median, 90th
    percentile, subjects above 150 mm PA-PVE, search failures, facing correct, seconds."""
    rows = report["results"]
    print(f"\n{label}\n")
    print(
        "| method | PA-PVE mean / median / p90 (mm) | PA-MPJPE mean / median / p90 (mm) | > 150 mm | search failures | facing correct | IoU | s/image |"
    )
    print("|---|---|---|---:|---:|---:|---:|---:|")
    for method in report["methods"]:
        r = [x for x in rows if x["method"] == method]
        col = lambda k: np.array([x[k] for x in r if k in x], dtype=np.float64)  # noqa: E731
        stats = lambda a: f"{a.mean():.1f} / {np.median(a):.1f} / {np.percentile(a, 90):.1f}" if len(a) else "-"  # noqa: E731
        pa = col("pa_pve")
        fail, facing, iou, t = col("search_failure"), col("facing_ok"), col("iou"), col("time_s")
        print(
            f"| {method} | {stats(pa)} | {stats(col('pa_mpjpe'))} | {int((pa > 150).sum())} of {len(pa)} | "
            f"{fail.mean() if len(fail) else float('nan'):.0f} % | {facing.mean():.0f} % | "
            f"{iou.mean() if len(iou) else float('nan'):.3f} | {t.mean() if len(t) else float('nan'):.2f} |"
        )


def run_dataset_benchmark(model, root, methods, label):
    """Both methods on an existing dataset in silfit's synthetic format (e.g. the hard set)."""
    from silfit.eval.evaluate import evaluate_dataset

    report = evaluate_dataset(root, fits=Path(root) / "fits", model=model, run=True, methods=methods)
    depth_branch_table(report, label)
    return report


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--subjects", type=int, default=50, help="generated subjects in random poses (0: none)")
    ap.add_argument("--synth", type=int, default=0, help="also N subjects from silfit's synthetic generator")
    ap.add_argument("--holdout", type=int, default=0, help="also the held-out pose-prior check on N subjects")
    ap.add_argument("--no-shipped", action="store_true")
    ap.add_argument("--prior", action="append", help="default | limits | PATH (repeatable; default: default)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="KeypointFitConfig override")
    ap.add_argument("--batch", type=int, default=32)
    ap.add_argument("--singles", type=int, default=5, help="subjects also fitted one by one for the timing")
    ap.add_argument("--noise", type=float, default=2.0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument(
        "--silhouette", type=int, default=0, help="keypoint-only vs keypoint+silhouette on N fresh subjects"
    )
    ap.add_argument("--size", type=int, default=512, help="image size of the --silhouette set")
    ap.add_argument("--keep", help="keep the --silhouette dataset and its fits in this folder")
    ap.add_argument(
        "--dataset",
        action="append",
        default=[],
        help="also score both methods on this synthetic-format dataset (repeatable)",
    )
    ap.add_argument("--keypoints-only", action="store_true", help="--dataset / --hard: the keypoint stage only")
    ap.add_argument(
        "--hard", type=int, default=0, help="also N fresh hard-pose subjects (silfit synth --poses hard, seed --seed)"
    )
    ap.add_argument("--silhouette-batches", help="time the silhouette stage alone and in batches, e.g. 1,8,16")
    ap.add_argument("--full-mesh", action="store_true", help="silhouette timing: render the full mesh, no proxy")
    ap.add_argument(
        "--whole-body",
        type=int,
        default=0,
        metavar="N",
        help="only the whole-body table (bench_wholebody.py) on N fresh whole-body subjects (seed --seed)",
    )
    args = ap.parse_args(argv)
    if args.whole_body:
        from bench_wholebody import run_wholebody_benchmark

        run_wholebody_benchmark(
            args.whole_body, args.seed, args.noise, args.size, min(args.batch, 16), args.singles, args.keep
        )
        return

    from silfit.fitting import KeypointFitConfig
    from silfit.priors import load_pose_prior

    if args.set and (args.silhouette or args.hard or args.dataset):  # they fit through evaluate_dataset's defaults
        ap.error(
            "--set applies to the generated random-pose sets only; --silhouette, --hard and --dataset fit with "
            "the defaults: compare code trees (git worktree) instead"
        )
    model = load_body_model()
    config = KeypointFitConfig(**parse_set(args.set))
    priors = args.prior or ["default"]
    fitters = {
        p: KeypointFitter(
            model, config=config, pose_prior=load_pose_prior(None if p == "default" else p, dtype=model.dtype)
        )
        for p in priors
    }
    if args.silhouette:
        report = run_silhouette_benchmark(model, args.silhouette, args.seed, args.noise, args.size, args.keep)
        depth_branch_table(report, f"silhouette set ({args.silhouette} subjects, seed {args.seed})")
    if args.silhouette_batches:
        from silfit.fitting.silhouette_stage import SilhouetteFitConfig

        cfg = (
            SilhouetteFitConfig(proxy_faces=None, render=Rendering(batch_render=False))
            if args.full_mesh
            else SilhouetteFitConfig()
        )
        silhouette_timing(model, [int(b) for b in args.silhouette_batches.split(",")], config=cfg)
    if args.hard:
        import tempfile

        from silfit.synth import generate_hard_dataset

        methods = ("keypoints",) if args.keypoints_only else ("keypoints", "silhouette")
        with tempfile.TemporaryDirectory() as tmp:
            root = Path(args.keep or tmp) / "hard"
            generate_hard_dataset(root, args.hard, seed=args.seed, size=args.size, noise_px=args.noise, model=model)
            run_dataset_benchmark(
                model, root, methods, f"hard set ({args.hard} subjects, seed {args.seed}, {args.noise:g} px noise)"
            )
    for root in args.dataset:
        methods = ("keypoints",) if args.keypoints_only else ("keypoints", "silhouette")
        run_dataset_benchmark(model, root, methods, f"dataset {root}")
    sets = []  # (name, data, {method: fitter})
    shipped = None if args.no_shipped else load_shipped()
    if shipped is not None:
        sets.append((f"shipped synthetic ({len(shipped['keypoints'])}, library poses)", shipped, fitters))
    if args.synth:
        sets.append(
            (
                f"silfit synth ({args.synth}, seed {args.seed}, library poses)",
                generate_synth(model, args.synth, args.seed, args.noise),
                fitters,
            )
        )
    if args.subjects:
        sets.append(
            (
                f"generated ({args.subjects}, {args.noise:g} px noise, random poses)",
                generate(model, args.subjects, args.seed, args.noise),
                fitters,
            )
        )
    if args.holdout:
        from silfit.priors import MaxMixturePrior
        from silfit.priors.library_prior import build_library_mixture, split_library

        half_a, half_b = split_library(args.seed)
        g = build_library_mixture(half_a)
        half = MaxMixturePrior(g["means"], g["covars"], g["weights"], source="library half A", dtype=model.dtype)
        hf = {
            f"half-A mixture ({len(half_a)} poses, held out)": KeypointFitter(model, config=config, pose_prior=half),
            "limits": fitters.get("limits") or KeypointFitter(model, config=config, pose_prior="limits"),
            "default (full library, has seen B)": fitters.get("default") or KeypointFitter(model, config=config),
        }
        sets.append(
            (
                f"held-out: poses from library half B only ({args.holdout})",
                generate_holdout(model, args.holdout, half_b, args.seed, args.noise),
                hf,
            )
        )

    if not sets:
        return
    print(
        "| set | prior | reproj px (mean/median) | MPJPE mm | PA-MPJPE mm | PVE mm | facing correct | s/image single | s/image batch %d |"
        % args.batch
    )
    print("|---|---|---|---|---|---|---|---|---|")
    for name, data, fits in sets:
        for method, fitter in fits.items():
            m, t1, tb = run_set(name, data, fitter, args.batch, args.singles)
            mm = lambda k: f"{1000 * np.mean(m[k]):.1f} / {1000 * np.median(m[k]):.1f}"  # noqa: E731
            print(
                f"| {name} | {method} | {np.mean(m['reproj']):.2f} / {np.median(m['reproj']):.2f} | {mm('mpjpe')} | "
                f"{mm('pa')} | {mm('pve')} | {100 * np.mean(m['facing']):.0f} % | {t1:.2f} | {tb:.2f} |",
                flush=True,
            )
    print(
        "\nNote: the default prior is built from silfit's pose library, which also poses the shipped and `silfit synth` "
        "subjects, so its numbers on those sets are optimistic; see the random-pose and held-out rows."
    )
    if args.holdout:
        print(
            f"Held-out split (seed {args.seed}): mixture built from half A = {', '.join(half_a)}; "
            f"subjects posed from half B = {', '.join(half_b)}."
        )


if __name__ == "__main__":
    main()
