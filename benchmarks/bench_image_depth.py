"""The image depth cue measured before it is weighted (issue 54): BlazePose GHUM's 3D landmarks against the truth.

Generates subjects (``silfit synth``: ``--poses hard`` and the easy default), runs the shipped landmark model
on their rendered images (:func:`silfit.detect.detect_people`), maps its landmarks to the body's joints
(shoulders, elbows, wrists, hips, knees, ankles: the same names) and compares, per limb segment whose two ends
differ in true depth by at least ``--min-dz`` metres, the sign of the cue's depth difference with the truth's,
as a function of the cue's own depth cosine ``|dz| / |v|`` (scale-free) and against the keypoint fit's signs
(``--fit``: the default keypoint stage on the generator's keypoints). Also the gated cue
(:func:`silfit.fitting.image_depth.depth_cue` with its defaults): how many segments it decides and how many
of those it gets right, and how many landmark sets it refuses (a left/right swap against the keypoints).

    python benchmarks/bench_image_depth.py --seeds 20000,20001 --n 15 --fit
"""

from __future__ import annotations

import argparse
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context
from pathlib import Path

import silfit  # noqa: F401  (first: the CPU kernels are pinned, silfit.kernels)
import numpy as np
import torch

from silfit import load_body_model
from silfit.camera import load_camera
from silfit.io.subjects import read_gt
from silfit.fitting.image_depth import SEGMENTS, ImageDepthConfig, depth_cue, mirrored_person, person_cue
from silfit.io.images import read_rgb
from silfit.io.keypoints import read_keypoints

BINS = (0.0, 0.1, 0.2, 0.3, 0.4, 0.6, 1.01)
#: the "mirror" settings' gates: both readings must agree (ImageDepthConfig.mirror), so the gates can be wider
MIRROR_GATES = ImageDepthConfig(off_below=0.3, full_at=0.5, max_disagreement=0.08, mirror=True)


def run_seed(seed: int, n: int, size: int, poses: str, fit: bool) -> list:
    """Per segment of each subject: true dz, cue cosine (world and image z), cue's gated call, fit's dz."""
    from silfit.detect import DetectionError, detect_people
    from silfit.fitting import KeypointFitter
    from silfit.synth.generate import SynthConfig, generate_dataset

    torch.set_num_threads(1)
    model = load_body_model()
    names = model.joint_names
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp) / "set"
        generate_dataset(
            root, n, SynthConfig(seed=seed, size=size, poses=poses, frontal_first=False), model=model, progress=False
        )
        dirs = sorted(d for d in root.iterdir() if (d / "keypoints.json").is_file())
        subjects = [
            (
                read_rgb(d / "image.png", "image"),
                read_keypoints(d / "keypoints.json"),
                load_camera(d / "camera.json"),
                read_gt(d / "gt.npz"),
            )
            for d in dirs
        ]
    fits = None
    t_fit = 0.0
    if fit:
        fitter = KeypointFitter(model)
        t0 = time.process_time()
        r = fitter.fit([s[1] for s in subjects], [s[2] for s in subjects], progress=False)
        t_fit = (time.process_time() - t0) / len(subjects)
        fits = r.joints.astype(np.float64)
    rows = []
    for i, (image, ks, cam, gt) in enumerate(subjects):
        t0 = time.perf_counter()
        try:
            person = detect_people(image)[0]
        except DetectionError:
            person = None
        t_det = time.perf_counter() - t0
        cue = (
            None
            if person is None
            else depth_cue(
                person.world, np.where(person.in_image(), person.visibility, 0.0), person.names, person.xy, ks
            )
        )
        mirror = mirrored_person(image, ks) if person is not None else None
        m_cue = None if mirror is None else person_cue(mirror, ks)
        for s, (seg, p, d) in enumerate(SEGMENTS):
            jp, jd = names.index(p), names.index(d)
            row = {
                "seed": seed,
                "i": i,
                "seg": seg,
                "dz": float(gt.joints[jd, 2] - gt.joints[jp, 2]),
                "t_det": t_det,
                "t_fit": t_fit,
                "found": person is not None,
            }
            if person is not None:
                lp, ld = person.names.index(p), person.names.index(d)
                v = person.world[ld] - person.world[lp]
                row.update(
                    cos=float(v[2] / np.linalg.norm(v)),
                    wdz=float(v[2]),
                    zdz=float(person.z[ld] - person.z[lp]),
                    vis=float(min(person.visibility[lp], person.visibility[ld])),
                    err2d=float(
                        max(
                            np.linalg.norm(person.xy[lp] - ks.xy[ks.names.index(p)]),
                            np.linalg.norm(person.xy[ld] - ks.xy[ks.names.index(d)]),
                        )
                    ),
                    call=float(cue.sign[s] * cue.confidence[s]),
                    m_cos=np.nan if m_cue is None else float(m_cue.ratio[s]),
                    m_call=0.0 if m_cue is None or m_cue.refused else float(m_cue.sign[s] * m_cue.confidence[s]),
                    refused=cue.refused is not None,
                )
            if fits is not None:
                row["fit_dz"] = float(fits[i, jd, 2] - fits[i, jp, 2])
            rows.append(row)
    return rows


def compare_seed(
    seed: int, n: int, size: int, poses: str, batch: int, variants: tuple, silhouette: bool = True
) -> list:
    """The default image path (keypoint stage in batches of ``batch``, then the silhouette stage against the
    generator's masks) per cue setting in ``variants`` (``(label, image_depth_weight, image_depth_decide)``; weight
    0 and decide ``None``: the cue off, the baseline), on the same subjects: per subject and setting PA-PVE (mm) of
    the keypoint stage and with silhouettes, CPU seconds."""
    from silfit.fitting import ImageDepthOptions, KeypointFitter, KeypointFitConfig
    from silfit.fitting.image_depth import cue_from_image
    from silfit.fitting.silhouette_stage import SilhouetteFitConfig
    from silfit.fitting.image_fit import refine_batch
    from silfit.eval.metrics import pa_pve
    from silfit.silhouette.masks import read_mask
    from silfit.synth.generate import SynthConfig, generate_dataset

    torch.set_num_threads(1)
    model = load_body_model()
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp) / "set"
        generate_dataset(
            root, n, SynthConfig(seed=seed, size=size, poses=poses, frontal_first=False), model=model, progress=False
        )
        dirs = sorted(d for d in root.iterdir() if (d / "keypoints.json").is_file())
        images = [read_rgb(d / "image.png", "image") for d in dirs]
        sets = [read_keypoints(d / "keypoints.json") for d in dirs]
        cams = [load_camera(d / "camera.json") for d in dirs]
        gts = [read_gt(d / "gt.npz") for d in dirs]
        masks = [read_mask(d / "mask.png") for d in dirs]
    t0 = time.process_time()
    image_cues = [cue_from_image(im, ks)[0] for im, ks in zip(images, sets)]
    t_cue = (time.process_time() - t0) / len(sets)
    oracles = [oracle_cue(gt.joints, model.joint_names) for gt in gts]
    mirrored = None
    if any("mirror" in v[0] for v in variants):  # the two readings' agreed calls, with wider gates
        t0 = time.process_time()
        mirrored = [cue_from_image(im, ks, config=MIRROR_GATES)[0] for im, ks in zip(images, sets)]
        t_mirror = (time.process_time() - t0) / len(sets)
    rows = []
    for label, w, decide in variants:
        on = bool(w) or decide is not None
        cues = oracles if "oracle" in label else mirrored if "mirror" in label else image_cues
        cue = ImageDepthOptions(
            float(w), decide=decide, decide_screens="reserve" not in label, decide_early="late" not in label
        )
        cfg = KeypointFitConfig(image_depth=cue)
        fitter = KeypointFitter(model, config=cfg)
        for b in range(0, len(sets), batch):
            sl = slice(b, b + batch)
            t0 = time.process_time()
            kp = fitter.fit(sets[sl], cams[sl], progress=False, depth_cues=cues[sl] if on else None)
            t_kp = time.process_time() - t0
            t0 = time.process_time()
            res = (
                refine_batch(
                    model, kp, sets[sl], masks[sl], SilhouetteFitConfig(), pose_prior=fitter.pose_prior, progress=False
                )
                if silhouette
                else [None] * len(kp)
            )
            t_sil = time.process_time() - t0
            for j, r in enumerate(res):
                gt = gts[b + j]
                c = cues[b + j]
                rows.append(
                    {
                        "seed": seed,
                        "i": b + j,
                        "w": label,
                        "t_kp": t_kp / len(res),
                        "t_sil": t_sil / len(res),
                        "t_cue": (t_mirror if "mirror" in label else t_cue) if on else 0.0,
                        "decided": 0 if c is None else len(c.decided()),
                        "hard": 0 if c is None or decide is None else int((c.hard_signs(decide) != 0).sum()),
                        "gap": choice_gap(kp.branch_search[j]),
                        "kp": 1000 * float(pa_pve(kp.vertices[j].astype(np.float64), gt.vertices)),
                        "sil": np.nan
                        if r is None
                        else 1000 * float(pa_pve(r.vertices.astype(np.float64), gt.vertices)),
                    }
                )
    return rows


def oracle_cue(joints: np.ndarray, joint_names, min_cos: float = 0.2):
    """A perfect cue (what-if: the truth's depth signs): every segment whose true depth cosine is at least
    ``min_cos`` decided on its true side, confidence 1; flatter ones off. Tells what the mechanisms
    (the term, the hard choice) could do with a landmark model that never errs."""
    from silfit.fitting.image_depth import DepthCue

    names = list(joint_names)
    ratio = np.zeros(len(SEGMENTS))
    for s, (_, p, d) in enumerate(SEGMENTS):
        v = joints[names.index(d)] - joints[names.index(p)]
        ratio[s] = v[2] / max(np.linalg.norm(v), 1e-9)
    on = np.abs(ratio) >= min_cos
    return DepthCue(np.where(on, np.sign(ratio), 0.0), on.astype(np.float64), ratio)


def choice_gap(search) -> float:
    """The relative final energy the fit's branch pays above the lowest refined one (0: the energy's own choice;
    above 0 where the image cue's hard choice took another)."""
    if not search or not search[-1].get("refined"):
        return 0.0
    low = min(t["energy"] for t in search[-1]["tried"])
    kept = next(t["energy"] for t in search[-1]["tried"] if t["flip"] == search[-1]["kept"])
    return (kept - low) / max(abs(low), 1e-12)


def compare_table(rows: list, weights: tuple) -> None:
    """The table of :func:`compare_seed`'s rows per setting label in ``weights`` (the first: the baseline)."""
    print(
        "| cue setting | subjects | keypoint stage PA-PVE mean / median (mm) | with silhouettes mean / median | "
        "> 150 mm | within 60 mm | CPU s / subject (cue, keypoints, silhouettes) |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|")
    for w in weights:
        r = [x for x in rows if x["w"] == w]
        kp, sil = np.array([x["kp"] for x in r]), np.array([x["sil"] for x in r])
        if np.isnan(sil).all():  # the keypoint stage only: the thresholds read its PA-PVE
            sil = kp
        print(
            f"| {w}{' (baseline)' if w == weights[0] else ''} | {len(r)} | {kp.mean():.1f} / {np.median(kp):.1f} | "
            f"{sil.mean():.1f} / {np.median(sil):.1f} | {(sil > 150).sum()} | {(sil <= 60).sum()} ({100 * (sil <= 60).mean():.0f} %) | "
            f"{np.mean([x['t_cue'] for x in r]):.2f}, {np.mean([x['t_kp'] for x in r]):.2f}, {np.mean([x['t_sil'] for x in r]):.2f} |"
        )
    for w in weights:
        hard = sum(x.get("hard", 0) for x in rows if x["w"] == w)
        if hard:
            print(f"\n{w}: {hard} segments decided (hard choice) over {sum(x['w'] == w for x in rows)} subjects")
    key = "kp" if all(np.isnan(x["sil"]) for x in rows) else "sil"
    base = {(x["seed"], x["i"]): x[key] for x in rows if x["w"] == weights[0]}
    for w in weights[1:]:
        d = {(x["seed"], x["i"]): x[key] - base[x["seed"], x["i"]] for x in rows if x["w"] == w}
        moved = [f"{k[0]}/{k[1]}: {base[k]:.0f} -> {base[k] + v:.0f}" for k, v in d.items() if abs(v) > 30]
        print(
            f"\n{w} against {weights[0]}, {'with silhouettes' if key == 'sil' else 'keypoint stage'}: {sum(v < -10 for v in d.values())} better by more than "
            f"10 mm, {sum(v > 10 for v in d.values())} worse; moved by more than 30 mm: {', '.join(moved) or 'none'}"
        )


def table(rows: list, min_dz: float, fit: bool) -> None:
    deep = [r for r in rows if abs(r["dz"]) >= min_dz and r["found"]]
    print(
        f"segments with |true dz| >= {min_dz} m: {len(deep)} (of {len(rows)}; subjects without a detection: "
        f"{len({(r['seed'], r['i']) for r in rows if not r['found']})})\n"
    )
    head = "| cue depth cosine | segments | cue sign right | image z sign right |" + (
        " fit right | cue right where the fit is wrong |" if fit else ""
    )
    print(head)
    print("|---:" * (head.count("|") - 1) + "|")
    right = lambda r, k: np.sign(r[k]) == np.sign(r["dz"])  # noqa: E731
    for lo, hi in zip(BINS[:-1], BINS[1:]):
        b = [r for r in deep if lo <= abs(r["cos"]) < hi]
        if not b:
            continue
        line = f"| {lo:.1f}-{min(hi, 1):.1f} | {len(b)} | {sum(right(r, 'wdz') for r in b)} | {sum(right(r, 'zdz') for r in b)} |"
        if fit:
            wrong = [r for r in b if not right(r, "fit_dz")]
            line += f" {len(b) - len(wrong)} | {sum(right(r, 'wdz') for r in wrong)} of {len(wrong)} |"
        print(line)
    tot = f"| all | {len(deep)} | {sum(right(r, 'wdz') for r in deep)} | {sum(right(r, 'zdz') for r in deep)} |"
    if fit:
        wrong = [r for r in deep if not right(r, "fit_dz")]
        tot += f" {len(deep) - len(wrong)} | {sum(right(r, 'wdz') for r in wrong)} of {len(wrong)} |"
    print(tot)
    called = [r for r in deep if r["call"]]
    subjects = {(r["seed"], r["i"]) for r in rows if r["found"]}
    refused = {(r["seed"], r["i"]) for r in rows if r.get("refused")}
    print(
        f"\nGated cue (ImageDepthConfig defaults): decides {len(called)} of these {len(deep)} segments, right on "
        f"{sum(np.sign(r['call']) == np.sign(r['dz']) for r in called)}; landmark sets refused: {len(refused)} of {len(subjects)}"
    )
    flat = [r for r in rows if abs(r["dz"]) < min_dz and r["found"] and r["call"]]
    print(
        f"Segments flatter than {min_dz} m it decides anyway: {len(flat)} (sign right on "
        f"{sum(np.sign(r['call']) == np.sign(r['dz']) for r in flat)})"
    )
    if fit:
        turn = [r for r in called if np.sign(r["call"]) != np.sign(r["fit_dz"])]
        print(
            f"Decided segments where the cue disagrees with the fit: {len(turn)}; the cue right on "
            f"{sum(np.sign(r['call']) == np.sign(r['dz']) for r in turn)} (what-if: signs only, no refit)"
        )
    det = sorted({(r["seed"], r["i"]): r["t_det"] for r in rows}.values())
    print(
        f"Landmark model (detector + 2 passes): {np.median(det):.2f} s median per image"
        + (f"; keypoint stage {np.mean([r['t_fit'] for r in rows]):.1f} CPU s per subject" if fit else "")
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="20000,20001", help="comma-separated generator seeds, --n subjects each")
    ap.add_argument("--n", type=int, default=15)
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument(
        "--poses", default="hard,library", help="pose sets, comma-separated (hard, library: the easy default)"
    )
    ap.add_argument("--min-dz", type=float, default=0.08)
    ap.add_argument("--fit", action="store_true", help="also the keypoint fit's signs")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--save", type=Path, help="write the per-segment rows here (pickle; for offline tuning)")
    ap.add_argument(
        "--compare",
        metavar="W0,W1",
        help="instead: fit with these image_depth_weight values (0: the cue "
        "off, the baseline) on the default image path (keypoints + silhouette) and compare",
    )
    ap.add_argument(
        "--decide",
        metavar="T0,T1",
        help="compare also (weight 0) with these image_depth_decide thresholds: the cue as a hard choice in the "
        "branch search (T/reserve: image_depth_decide_screens off, T/late: image_depth_decide_early off, both: T/reserve/late; implies --compare 0 where --compare is not given, "
        "--compare none: no baseline)",
    )
    ap.add_argument(
        "--oracle-weight",
        metavar="W0,W1",
        help="compare also with the truth's depth signs as the cue (a what-if: a landmark model that never errs) "
        "through the term at these weights; T/oracle in --decide: the same through the hard choice",
    )
    ap.add_argument(
        "--mirror-weight",
        metavar="W0,W1",
        help="compare also with the cue read twice (the image and its mirror image, MIRROR_GATES) through the term",
    )
    ap.add_argument("--batch", type=int, default=8, help="--compare: subjects per keypoint-stage batch")
    ap.add_argument(
        "--no-silhouette",
        action="store_true",
        help="--compare: the keypoint stage only (the table's thresholds then read the keypoint stage's PA-PVE)",
    )
    args = ap.parse_args()
    seeds = [int(s) for s in args.seeds.split(",")]
    t0 = time.perf_counter()
    if args.compare or args.decide:
        compare = (args.compare or "0").split(",") if args.compare != "none" else []
        variants = tuple((f"weight {float(w):g}", float(w), None) for w in compare)
        for w in (args.oracle_weight or "").split(","):  # the truth's signs as the cue, through the term
            if w:
                variants += ((f"oracle weight {float(w):g}", float(w), None),)
        for w in (args.mirror_weight or "").split(","):  # the two readings' agreed calls, through the term
            if w:
                variants += ((f"mirror weight {float(w):g}", float(w), None),)
        for t in (args.decide or "").split(
            ","
        ):  # T, T/reserve (image_depth_decide_screens off), T/late (..._early off)
            if t:
                label = " ".join([f"decide {float(t.split('/')[0]):g}"] + t.split("/")[1:])
                label = label.replace("decide", "oracle decide") if "oracle" in t else label
                label = label.replace(" oracle", "") if "oracle" in t else label
                variants += ((label, 0.0, float(t.split("/")[0])),)
        weights = tuple(v[0] for v in variants)
        with ProcessPoolExecutor(args.workers, mp_context=get_context("spawn")) as pool:
            jobs = {
                (p, s): pool.submit(compare_seed, s, args.n, args.size, p, args.batch, variants, not args.no_silhouette)
                for p in args.poses.split(",")
                for s in seeds
            }
            out = {k: j.result() for k, j in jobs.items()}
        if args.save:
            import pickle

            args.save.write_bytes(pickle.dumps(out))
        for p in args.poses.split(","):
            what = "keypoint stage only" if args.no_silhouette else "keypoints + silhouette"
            print(
                f"\n## {p} poses: {args.n} subjects per seed, seeds {args.seeds}, {args.size} px, {what} "
                f"({time.perf_counter() - t0:.0f} s wall for all, {args.workers} processes)\n"
            )
            compare_table([r for s in seeds for r in out[p, s]], weights)
        return
    with ProcessPoolExecutor(args.workers, mp_context=get_context("spawn")) as pool:
        jobs = {
            (p, s): pool.submit(run_seed, s, args.n, args.size, p, args.fit)
            for p in args.poses.split(",")
            for s in seeds
        }
        out = {k: j.result() for k, j in jobs.items()}
    if args.save:
        import pickle

        args.save.write_bytes(pickle.dumps(out))
    for p in args.poses.split(","):
        print(
            f"\n## {p} poses: {args.n} subjects per seed, seeds {args.seeds}, {args.size} px "
            f"({time.perf_counter() - t0:.0f} s wall for all)\n"
        )
        table([r for s in seeds for r in out[p, s]], args.min_dz, args.fit)


if __name__ == "__main__":
    main()
