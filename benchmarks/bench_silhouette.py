"""The silhouette stage before and after issue 24, measured in one run; prints Markdown tables.

"original" is the stage as issue 24 found it (:meth:`SilhouetteFitConfig.legacy` rendered with Mitsuba's
``prb_projective``); "before" is :meth:`SilhouetteFitConfig.legacy` (rendered Adam levels only: 60 steps at
128 px, 50 at 256 px); "after" is the default (a contour level: L-BFGS on the contour
surrogate, no rendering, then a short rendered level). Both start from the same keypoint
fits of fresh synthetic subjects (``--seed``; not the seeds the defaults were tuned on:
4242) and run in this process, one after the other.

Sets:

* ``--single N``: N single-image subjects (:func:`silfit.synth.generate_dataset`, ``--size``
  px, 2 px keypoint noise), one silhouette-stage call per subject;
* ``--rig N``: N 4-view rigs (:mod:`silfit.synth.camera_rigs`, views 0, 2, 4, 6 of an 8-camera
  ring), one call per rig (every view's mask rendered);
* ``--kornia``: the mask distance transform with kornia against OpenCV's exact one.

Per method: seconds per image (or rig) in the stage (in-process, ``time.perf_counter``
around the call) and the wall time of the whole fit per image (keypoint stage share +
silhouette stage + windows/targets), rendered steps and contour iterations per call,
full-image mask IoU (the fit rendered with pyrender/OSMesa against the mask; mean over
views for rigs), PVE (root-aligned) and PA-PVE in mm against the truth.

``head`` is the stage at main before issue 24's third part (``HEAD``: the ray-cast renderer, a short contour
level, 65 rendered steps, the full mesh posed each step); ``third`` is the stage before issue 24's fourth part
(a longer contour level at higher weights, 50 rendered steps, the 10,000-face render proxy posed directly; this
method was called ``main`` before the speed part); ``main`` is the default before issue 24's speed part
(``edge_density=None``: ``edge_spp`` visibility-edge points per window pixel); ``after`` is the default
(``edge_density=3``: 3 edge points per pixel of contour-candidate length, 2 rays per edge pixel, since the sampling
part, 4 and 4 before it; before the speed part: coarser render proxies per
level, 3,000 faces at 128 px and 5,000 at 256 px, a 10-step warm-up and half body_pose's learning rate);
``--step`` times one render + backward of the default 256 px level per method (``main``/``after``'s edge points);
``prev`` is the default before issue 24's runtime part (the same configuration and fits bit for bit as ``dense``: the
edge integral's vertex gradient by autograd over every vertex, the stage's reduced bodies rebuilt each call; methods
older than ``after`` run so too, :data:`OLD_RUNTIME`); ``dense`` is the default before issue 24's sampling part (4
rays per edge pixel and 4 visibility-edge points per pixel of candidate length, :data:`BEFORE_SAMPLING_PART`; the
cover term's nearest points from one float32 product over all pairs, not a k-d tree: methods older than ``after``
run so too, :data:`PRODUCT_NN`); ``dense-tree`` is ``dense`` with the k-d tree (the nearest points' share of the
change); ``head-projective`` is ``head`` rendered with
Mitsuba's ``prb_projective`` integrator; ``after-1t``: the default with one Dr.Jit thread (the same fits bit for bit; see ``ONE_THREAD``); ``after-stratified``, ``*-s1``: see ``RENDERERS``; ``weakprior`` is the default with the stage's
pose prior weight before issue 23's detected-inputs part (0.002, now 0.005).
``--video 60``: one 60-frame synthetic walk through the sequence's stage (``refine_sequence_silhouettes``: all
frames one problem), seconds per frame (methods with their own renderer are skipped there).
Methods run interleaved per subject; ``--base`` names the row the ratios are taken against.

The machine is shared: compare the rows of one run (ratios), not runs.

    python benchmarks/bench_silhouette.py --single 4 --step --methods main,after --base main --seed 9300
    python benchmarks/bench_silhouette.py --single 6 --rig 4 --methods head,after --base head
    python benchmarks/bench_silhouette.py --single 8 --rig 3 --video 60 --methods original,head,after \
        --video-methods head,after --base original --seed 9700

    python benchmarks/bench_silhouette.py --single 30 --rig 10 --seed 9100
    python benchmarks/bench_silhouette.py --single 4 --seed 9100 --methods after   # a quick look
"""

from __future__ import annotations

import argparse
import tempfile
import time
from contextlib import contextmanager
from pathlib import Path

import silfit  # noqa: F401  (first: the CPU kernels are pinned before numpy and torch load, silfit.kernels)
import numpy as np
import torch

from silfit import load_body_model
from silfit.fitting.silhouette_stage import (
    BEFORE_FOURTH_PART,
    BEFORE_SAMPLING_PART,
    RENDER_SETTINGS,
    Rendering,
    SilhouetteFitConfig,
    fit_silhouette,
    fit_silhouette_problems,
)
from silfit.runner.worker import config_with

#: the stage at main before issue 24's third part (a 20-iteration contour level at weights 0.05, then 40 + 25
#: rendered steps, the full mesh posed each step and mapped to the render proxy)
HEAD = {
    "iterations": (40, 25),
    "contour_iterations": 20,
    "w_contour_inside": 0.05,
    "w_contour_cover": 0.05,
    "proxy_body": False,
    **BEFORE_FOURTH_PART,
}
#: the stage at main before issue 24's fourth part (a 10,000-face proxy at both rendered levels, a 5-step warm-up,
#: body_pose's learning rate 0.03): the third part's default
THIRD = BEFORE_FOURTH_PART
#: the default before issue 24's speed part: edge_spp visibility-edge points per window pixel
MAIN = {**BEFORE_SAMPLING_PART, "edge_density": None}


def flat_config(changes: dict) -> SilhouetteFitConfig:
    """The stage's settings with ``changes``, flat as the tables above keep them (the rendering settings by their
    names before the ``render`` group)."""
    grouped = {(f"render.{k}" if k in RENDER_SETTINGS else k): v for k, v in changes.items()}
    return config_with(SilhouetteFitConfig, grouped, stage="silhouette")


METHODS = {
    "original": SilhouetteFitConfig.legacy,
    "before": SilhouetteFitConfig.legacy,
    "after": SilhouetteFitConfig,
    "head": lambda: flat_config(HEAD),
    "third": lambda: flat_config(THIRD),
    "main": lambda: flat_config(MAIN),
    "head-projective": lambda: flat_config(HEAD),
    "after-1t": SilhouetteFitConfig,
    "after-stratified": SilhouetteFitConfig,
    "head-s1": lambda: flat_config({**HEAD, "seed": 1}),
    "after-s1": lambda: SilhouetteFitConfig(render=Rendering(seed=1)),
    "prev": lambda: flat_config(BEFORE_SAMPLING_PART),
    "dense": lambda: flat_config(BEFORE_SAMPLING_PART),
    "dense-tree": lambda: flat_config(BEFORE_SAMPLING_PART),
    "weakprior": lambda: SilhouetteFitConfig(pose_weight=0.002),
}
#: methods run as before issue 24's runtime part (the edge integral's vertex gradient by torch's autograd over every
#: vertex, the stage's reduced bodies rebuilt each call): ``prev`` is the default so (the same fits bit for bit)
OLD_RUNTIME = {"original", "before", "head", "third", "main", "head-projective", "head-s1", "prev"}
#: methods whose cover term finds its nearest points by the float32 product over all pairs, as before issue 24's
#: sampling part (``silfit.silhouette.losses.NEAREST_BY_TREE`` off)
PRODUCT_NN = OLD_RUNTIME | {"dense"}
#: methods run with one Dr.Jit thread, as the ray-cast renderer did before issue 24's threads part (the same fits bit
#: for bit); the others with Dr.Jit's whole pool (``--drjit-threads``, default: the host's cores)
ONE_THREAD = OLD_RUNTIME | {"after-1t"}
DRJIT_POOL = None  # set in main()


@contextmanager
def runtime(name):
    """Method ``name``'s runtime: before issue 24's runtime part for :data:`OLD_RUNTIME` (no vertex-gradient
    shortcut, no kept bodies), else today's."""
    global DRJIT_POOL
    from silfit.render._llvm import import_mitsuba
    from silfit.render.raycast import RaycastScene
    from silfit.fitting import silhouette_stage
    from silfit.silhouette import losses

    _, dr = import_mitsuba()
    DRJIT_POOL = DRJIT_POOL or dr.thread_count()  # the pool as Dr.Jit started, before a method set it to one
    old = name in OLD_RUNTIME
    RaycastScene.analytic_grad = not old
    if old:
        silhouette_stage._CONTOUR_BODIES.clear()
    dr.set_thread_count(1 if name in ONE_THREAD else DRJIT_POOL)
    losses.NEAREST_BY_TREE = name not in PRODUCT_NN
    try:
        yield
    finally:
        RaycastScene.analytic_grad = True
        losses.NEAREST_BY_TREE = True


#: the renderer per method (``None``: the stage's default, the ray-cast method since issue 24's second part):
#: ``original`` and ``head-projective`` render with Mitsuba's ``prb_projective`` (the renderer before the ray-cast
#: method),
#: ``after-stratified`` with stratified pixel samples and evenly spaced edge points (lower noise, same expectation;
#: measured worse on a 4-view rig: the stage's Adam settings were tuned with independent samples' noise);
#: ``*-s1``: the renderer's base seed 1 instead of 0 (the spread a seed alone gives)
RENDERERS = {
    "original": {"method": "projective"},
    "head-projective": {"method": "projective"},
    "after-stratified": {"sampler": "stratified", "edge_sampling": "systematic"},
}


def renderer_for(model, name):
    """The renderer of method ``name`` (a proxy renderer like the stage's default), or ``None``."""
    options = RENDERERS.get(name)
    if options is None:
        return None
    from silfit.render.proxy import ProxySilhouetteRenderer, get_proxy

    cfg = METHODS[name]()
    return ProxySilhouetteRenderer(get_proxy(model.v_template, model.faces, int(cfg.proxy_faces)), **options)


def body(model, params):
    t = {k: torch.as_tensor(np.asarray(v, np.float32).reshape(1, -1)) for k, v in params.items()}
    with torch.no_grad():
        out = model(**t)
    return out.vertices[0].double().numpy(), out.joints[0].double().numpy()


def single_scores(model, params, s) -> dict:
    from silfit.render.offscreen import render_mask
    from silfit.eval.metrics import mask_iou, pa_pve, pve

    V, J = body(model, params)
    mask = render_mask(V.astype(np.float32), model.faces.numpy(), s.camera)
    return {
        "iou": mask_iou(mask, s.mask),
        "pve": 1000 * pve(V, s.gt.vertices, J[0], s.gt.joints[0]),
        "pa_pve": 1000 * pa_pve(V, s.gt.vertices),
    }


BASE = "before"


def table(title, rows, unit="image"):
    print(f"\n### {title}\n")
    print(
        f"| method | s/{unit} stage (in-process) | s/{unit} wall (whole fit) | rendered steps | contour iterations | "
        "IoU mean | PVE mm mean | PA-PVE mm mean / median |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|---|")
    base = rows.get(BASE) or rows.get("before")
    for name, r in rows.items():
        a = {k: np.array(v, dtype=np.float64) for k, v in r.items()}
        ratio = f" ({np.mean(base['stage']) / a['stage'].mean():.2f}x)" if base and a["stage"].mean() > 0 else ""
        wall_ratio = f" ({np.mean(base['wall']) / a['wall'].mean():.2f}x)" if base else ""
        print(
            f"| {name} | {a['stage'].mean():.2f}{ratio} | {a['wall'].mean():.2f}{wall_ratio} | {a['steps'].mean():.0f} | "
            f"{a['contour'].mean():.0f} | {a['iou'].mean():.4f} | {a['pve'].mean():.2f} | "
            f"{a['pa_pve'].mean():.2f} / {np.median(a['pa_pve']):.2f} |"
        )
    if base and len(rows) > 1:
        for name, r in rows.items():
            if r is base or name == "keypoints only":
                continue
            d_iou = np.array(r["iou"]) - np.array(base["iou"])
            d_pa = np.array(r["pa_pve"]) - np.array(base["pa_pve"])
            print(
                f"\n{name} - {BASE if BASE in rows else 'before'}, per {unit}: IoU {d_iou.mean():+.4f} (min {d_iou.min():+.4f}), "
                f"PA-PVE {d_pa.mean():+.2f} mm (max {d_pa.max():+.2f})"
            )


def run_single(model, n, seed, size, methods):
    from silfit.io.subjects import list_subjects, load_subject
    from silfit.fitting import KeypointFitter
    from silfit.synth import generate_dataset
    from silfit.synth.generate import SynthConfig

    with tempfile.TemporaryDirectory() as tmp:
        generate_dataset(tmp, n, SynthConfig(seed=seed, size=size, noise_px=2.0), model=model)
        subjects = [load_subject(p) for p in list_subjects(tmp)]
    fitter = KeypointFitter(model)
    t0 = time.perf_counter()
    kp = fitter.fit([s.keypoints for s in subjects], [s.camera for s in subjects], progress=False)
    kp_share = (time.perf_counter() - t0) / n
    rows = {"keypoints only": {"stage": [0.0] * n, "wall": [kp_share] * n, "steps": [0] * n, "contour": [0] * n}}
    for k, v in zip(
        ("iou", "pve", "pa_pve"), zip(*[single_scores(model, kp.params(i), s).values() for i, s in enumerate(subjects)])
    ):
        rows["keypoints only"][k] = list(v)
    # methods interleaved per subject, so a change in the machine's load hits them alike
    setups = {name: (METHODS[name](), renderer_for(model, name)) for name in methods}
    for name in methods:
        rows[name] = {k: [] for k in ("stage", "wall", "steps", "contour", "iou", "pve", "pa_pve")}
    for i, s in enumerate(subjects):
        for name, (cfg, renderer) in setups.items():
            r = rows[name]
            with runtime(name):
                t = time.perf_counter()
                res = fit_silhouette(
                    model,
                    kp.params(i),
                    s.camera,
                    s.mask,
                    s.keypoints.as_array(),
                    config=cfg,
                    pose_prior=fitter.pose_prior,
                    progress=False,
                    renderer=renderer,
                )
                dt = time.perf_counter() - t
            r["stage"].append(res.seconds)
            r["wall"].append(kp_share + dt)
            r["steps"].append(res.steps)
            r["contour"].append(res.contour_iterations)
            for k, v in single_scores(model, res.params(), s).items():
                r[k].append(v)
        print(f"single images: subject {i + 1}/{n} done", flush=True)
    table(f"Single images: {n} subjects, {size} px, seed {seed}", rows)
    return rows


def run_rig(model, n, seed, size, methods):
    from silfit.eval.score_rig import score_rig_fit, subset_truth
    from silfit.fitting.keypoint_stage import KeypointFitter
    from silfit.fitting.problem import Problem
    from silfit.fitting.rig_fit import fit_rig_keypoints
    from silfit.inputs.rig import rig_problem
    from silfit.io.rig import load_rig
    from silfit.synth.generate import SynthConfig
    from silfit.synth.camera_rigs import RigConfig, generate_rig_dataset
    from dataclasses import replace

    idx = [0, 2, 4, 6]
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        generate_rig_dataset(root, n, SynthConfig(seed=seed, size=size, noise_px=2.0), RigConfig(views=8), model=model)
        subjects = []
        for i in range(n):
            d = root / f"subject_{i:03d}"
            views = load_rig(d)
            gt = np.load(d / "gt.npz")
            problem = rig_problem(views)
            obs = [o for o in problem.observations if o.view_index in idx]
            problem = Problem([replace(o, view_index=idx.index(o.view_index)) for o in obs], problem.shared)
            subjects.append(([views[j] for j in idx], problem, subset_truth({k: gt[k] for k in gt.files}, idx)))
    fitter = KeypointFitter(model)
    t0 = time.perf_counter()
    fits = fit_rig_keypoints(fitter, [p for _, p, _ in subjects])
    kp_share = (time.perf_counter() - t0) / n

    def scores(views, problem, truth, params):
        m = score_rig_fit(model, views, problem, truth, params)
        return {"iou": m["iou"], "pve": m["pve_world"], "pa_pve": m["pa_pve"]}

    rows = {"keypoints only": {"stage": [0.0] * n, "wall": [kp_share] * n, "steps": [0] * n, "contour": [0] * n}}
    for k in ("iou", "pve", "pa_pve"):
        rows["keypoints only"][k] = [scores(v, p, g, f.params)[k] for (v, p, g), f in zip(subjects, fits)]
    setups = {name: (METHODS[name](), renderer_for(model, name)) for name in methods}
    for name in methods:
        rows[name] = {k: [] for k in ("stage", "wall", "steps", "contour", "iou", "pve", "pa_pve")}
    for i, ((views, problem, truth), f) in enumerate(zip(subjects, fits)):
        for name, (cfg, renderer) in setups.items():
            r = rows[name]
            with runtime(name):
                t = time.perf_counter()
                (res,) = fit_silhouette_problems(
                    model,
                    [problem],
                    [dict(f.params)],
                    config=cfg,
                    pose_prior=fitter.pose_prior,
                    progress=False,
                    renderer=renderer,
                )
                dt = time.perf_counter() - t
            r["stage"].append(res.seconds)
            r["wall"].append(kp_share + dt)
            r["steps"].append(res.steps)
            r["contour"].append(res.contour_iterations)
            params = {k: np.asarray(v).reshape(-1) for k, v in res.parameters.items()}
            for k, v in scores(views, problem, truth, params).items():
                r[k].append(v)
        print(f"rigs: rig {i + 1}/{n} done", flush=True)
    table(f"4-view rigs: {n} rigs, {size} px, seed {seed} (PVE: world, no alignment)", rows, unit="rig")
    return rows


def run_step(model, methods, resolutions=(128, 256), repeats=15):
    """One rendered step of each level (render + backward of a weighted coverage sum, the level's default
    render proxy, a window of the level's size around a standing body, the stage's torch threads) per method,
    methods interleaved: median milliseconds and edge points per call (the methods' ``edge_density``)."""
    from silfit.render.proxy import get_proxy
    from silfit.render.silhouette import get_silhouette_renderer, roi_window
    from silfit.camera import Camera
    from silfit.fitting.threads import torch_threads

    cam = Camera.from_image_size(512, 512)
    with torch.no_grad():
        v = model(transl=torch.tensor([[0.0, 0.2, 3.0]]), global_orient=torch.tensor([[np.pi, 0.0, 0.0]])).vertices[0]
    print(f"\n### One rendered step (render + backward), median of {repeats}, methods interleaved\n")
    print("| method | level px | proxy faces | ms per step | ratio |")
    print("|---|---:|---:|---:|---:|")
    for res in resolutions:
        setups = {}
        for name in methods:
            cfg = METHODS[name]()
            proxy = get_proxy(model.v_template, model.faces, int(cfg.level_faces(res) or cfg.proxy_faces))
            pv = proxy(v)
            window = roi_window(pv, cam, size=res, margin=cfg.margin)
            w = torch.linspace(-1.0, 1.0, window.camera.width)[None, :].expand(window.camera.height, -1)
            setups[name] = (cfg, len(proxy.faces), pv, window.camera, get_silhouette_renderer(proxy.faces), w, [])
        with torch_threads(METHODS[methods[0]]().threads):
            for k in range(repeats + 2):
                for name, (cfg, _, pv, wcam, r, w, ts) in setups.items():
                    dens = {} if cfg.render.edge_density is None else {"edge_density": cfg.render.edge_density}
                    x = pv.clone().requires_grad_()
                    with runtime(name):
                        t = time.perf_counter()
                        img = r.render_views(
                            x,
                            [wcam],
                            [torch.eye(3)],
                            [torch.zeros(3)],
                            spp=cfg.render.spp,
                            edge_spp=cfg.render.edge_spp,
                            seeds=[k],
                            **dens,
                        )[0]
                        (img * w).sum().backward()
                    if k >= 2:
                        ts.append(time.perf_counter() - t)
        base_ms = None
        for name, (cfg, n_faces, _, _, _, _, ts) in setups.items():
            ms = 1000 * float(np.median(ts))
            base_ms = base_ms or ms
            print(f"| {name} | {res} | {n_faces} | {ms:.1f} | {base_ms / ms:.2f}x |")


def run_kornia(size=512, repeats=5):
    """kornia's distance transform against OpenCV's exact Euclidean one on a body mask."""
    import cv2

    from silfit.render.offscreen import render_mask
    from silfit.camera import Camera

    model = load_body_model()
    with torch.no_grad():
        v = model(transl=torch.tensor([[0.0, 0.2, 3.0]]), global_orient=torch.tensor([[np.pi, 0.0, 0.0]])).vertices[0]
    mask = render_mask(v.numpy(), model.faces.numpy(), Camera.from_image_size(size, size))
    out = ~mask

    def best(fn):
        ts = []
        for _ in range(repeats):
            t = time.perf_counter()
            r = fn()
            ts.append(time.perf_counter() - t)
        return r, 1000 * min(ts)

    exact, t_cv = best(lambda: cv2.distanceTransform(out.astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE))
    print(f"\n### Distance transform of a {size}x{size} body mask\n")
    print("| method | ms | max abs error vs exact (px) | mean abs error (px) |")
    print("|---|---:|---:|---:|")
    print(f"| OpenCV DIST_L2 / DIST_MASK_PRECISE | {t_cv:.1f} | 0 | 0 |")
    try:
        import kornia
    except ImportError:
        print("| kornia | not installed | | |")
        return
    img = torch.as_tensor(mask, dtype=torch.float32)[None, None]
    k, t_k = best(lambda: kornia.contrib.distance_transform(img)[0, 0].numpy())
    err = np.abs(k - exact)
    print(
        f"| kornia.contrib.distance_transform {kornia.__version__} | {t_k:.1f} | {err.max():.1f} | {err.mean():.2f} |"
    )


def run_video(model, frames, seed, size, methods):
    """One synthetic walk of ``frames`` frames: the temporal keypoint fit, then the sequence's silhouette
    stage (:func:`silfit.fitting.sequence.refine_sequence_silhouettes`: one problem of all frames, one shape)
    per method; seconds per frame of the stage, silhouette IoU, PA-MPJPE and acceleration error."""
    from silfit.camera import load_camera
    from silfit.eval.score_sequence import score_sequence
    from silfit.fitting.sequence import fit_sequence, refine_sequence_silhouettes
    from silfit.silhouette.masks import read_mask
    from silfit.synth.motion import SequenceConfig, generate_sequence_dataset
    from silfit.io.video import read_sequence

    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        generate_sequence_dataset(
            root, 1, SequenceConfig(seed=seed, frames=frames, size=size, noise_px=2.0, drop_prob=0.1), model=model
        )
        d = root / "seq_000"
        seq = read_sequence(d)
        cam = load_camera(d / "camera.json")
        gt = dict(np.load(d / "gt.npz"))
        masks = [read_mask(seq.masks[n]) for n in seq.numbers]
    t = time.perf_counter()
    fit = fit_sequence(seq.frames, cam, model)
    kp_seconds = (time.perf_counter() - t) / frames
    rows = {"keypoints only": {**score_sequence(model, gt, fit.params()), "stage": 0.0, "iou": float("nan")}}
    for name in methods:
        if name in RENDERERS:  # refine_sequence_silhouettes renders with the stage's default renderer only
            print(f"video: {name} skipped (its renderer is not the stage's default)", flush=True)
            continue
        with runtime(name):
            t = time.perf_counter()
            r = refine_sequence_silhouettes(model, fit, seq.frames, masks, config=METHODS[name]())
            dt = time.perf_counter() - t
        rows[name] = {
            **score_sequence(model, gt, r.params()),
            "stage": dt / frames,
            "iou": float(np.nanmean(r.silhouette_iou)),
        }
        print(f"video: {name} done ({dt:.0f} s)", flush=True)
    print(f"\n### Video: one {frames}-frame walk, {size} px, seed {seed} (keypoint fit {kp_seconds:.2f} s/frame)\n")
    print(
        "| method | s/frame stage (in-process) | silhouette IoU (window) | PA-MPJPE mm | acceleration error mm/frame^2 | "
        "shape error mm |"
    )
    print("|---|---:|---:|---:|---:|---:|")
    base = rows.get(BASE) or rows.get("head")  # the video case may leave the slow original out
    for name, r in rows.items():
        ratio = f" ({base['stage'] / r['stage']:.2f}x)" if base and r["stage"] > 0 else ""
        print(
            f"| {name} | {r['stage']:.2f}{ratio} | {r['iou']:.4f} | {r['pa_mpjpe']:.1f} | {r['accel']:.1f} | {r['shape']:.1f} |"
        )
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--single", type=int, default=0, help="single-image subjects")
    ap.add_argument("--rig", type=int, default=0, help="4-view rigs")
    ap.add_argument("--seed", type=int, default=9100)
    ap.add_argument("--size", type=int, default=512)
    ap.add_argument("--methods", default="before,after", help="comma-separated: " + ", ".join(METHODS))
    ap.add_argument("--base", default="before", help="the method the ratios are taken against")
    ap.add_argument(
        "--video",
        type=int,
        default=0,
        metavar="FRAMES",
        help="a synthetic walk of FRAMES frames (60: the issue's video case) through the sequence's stage",
    )
    ap.add_argument("--video-methods", default=None, help="methods of the video case (default: --methods)")
    ap.add_argument("--kornia", action="store_true", help="also time kornia's distance transform against OpenCV's")
    ap.add_argument("--step", action="store_true", help="also time one rendered step per level and method")
    ap.add_argument(
        "--drjit-threads",
        type=int,
        default=None,
        help="Dr.Jit's pool for the methods not in ONE_THREAD (default: as Dr.Jit starts, the host's cores)",
    )
    args = ap.parse_args(argv)
    global BASE, DRJIT_POOL
    BASE = args.base
    from silfit.render._llvm import import_mitsuba

    DRJIT_POOL = args.drjit_threads or import_mitsuba()[1].thread_count()
    methods = [m for m in args.methods.split(",") if m]
    unknown = [m for m in methods if m not in METHODS]
    if unknown:
        raise SystemExit(f"--methods: unknown {unknown} (known: {', '.join(METHODS)})")
    torch.manual_seed(0)
    model = load_body_model()
    if args.single:
        run_single(model, args.single, args.seed, args.size, methods)
    if args.rig:
        run_rig(model, args.rig, args.seed + 1, args.size, methods)
    if args.video:
        vm = [m for m in (args.video_methods or args.methods).split(",") if m]
        run_video(model, args.video, args.seed + 2, args.size, vm)
    if args.step:
        run_step(model, methods)
    if args.kornia:
        run_kornia(args.size)


if __name__ == "__main__":
    main()
