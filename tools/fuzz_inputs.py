"""Fuzz ``silfit fit`` in-process with generated broken and hostile inputs; print how many
cases gave clean errors, successes and crashes (target: 0 crashes).

Every case starts from a valid input set (OpenPose keypoints, ``camera.json``, a person
mask PNG, an image, the small capsule body model of the tests, the shipped pose prior)
and applies 1-3 random mutations: junk values in keypoint/camera fields (strings,
booleans, nulls, NaN/inf, 1e30, 10**400, negatives), wrong structures and lengths,
degenerate keypoints (one place, a few pixels, far outside the image), truncated,
bit-flipped, random and UTF-16 bytes, masks and images of other sizes, modes and
formats (palette, 1-bit, 16-bit, float TIFF, colour, alpha, noise, empty, all white, a
header claiming 100000 px), corrupted model and pose-prior files, hostile pickles, and
odd option values (``--person``, ``--image-size``, ``--focal``, ``--silhouette-*``).

Each case runs ``silfit.cli.main([... "fit", ..., "--check-only"])``: every reader and
check up to the fit (keypoints, image, camera, mask, model, pose prior, plausibility).
Every ``--fit-every``-th case that passes them is then run again without
``--check-only`` and with ``--no-silhouette``: the keypoint stage is fitted and the output
folder written. Outcomes: **ok** (exit 0), **clean error** (exit 2 with one line
``silfit fit: error: ...`` on stderr), **crash** (anything else: an exception escaping
``main``, another exit status, a traceback or several lines, an output folder left
behind by a failed run).

    python tools/fuzz_inputs.py --cases 10000 --seed 0
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import pickle
import random
import shutil
import sys
import tempfile
import time
import traceback
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests" / "fitting"))  # the tests' capsule body model: fast to load and fit

import silfit  # noqa: E402, F401  (first: the CPU kernels are pinned before numpy and torch load, silfit.kernels)
import numpy as np  # noqa: E402

JUNK = [
    float("nan"),
    float("inf"),
    float("-inf"),
    1e30,
    -1e30,
    10**400,
    -5,
    0,
    1e-300,
    "12",
    "x",
    None,
    True,
    False,
    [],
    {},
    [1, 2],
    {"x": 1},
]


# ----------------------------------------------------------------------------- valid inputs
def valid_inputs(d: Path) -> dict:
    import torch
    from PIL import Image

    from silfit.camera import Camera, project_points
    from silfit.io.keypoints import model_keypoints
    from silfit_toy_body import toy_model, write_toy_npz

    model_path = write_toy_npz(d / "toy.npz")
    m = toy_model()
    out = m(global_orient=torch.tensor([[np.pi, 0, 0]]), transl=torch.tensor([[0.0, 0.2, 3.0]]))
    cam = Camera.from_image_size(160, 120)
    xy = project_points(model_keypoints(m, out, "body25"), cam)[0].numpy()
    mask = np.zeros((120, 160), np.uint8)
    lo, hi = xy.min(0).astype(int), xy.max(0).astype(int)
    mask[max(lo[1], 0) : hi[1], max(lo[0], 0) : hi[0]] = 255
    image = np.dstack([mask // 2 + 60] * 3).astype(np.uint8)
    Image.fromarray(mask).save(d / "mask.png")
    Image.fromarray(image).save(d / "image.png")
    return {
        "keypoints": {
            "version": 1.3,
            "people": [{"pose_keypoints_2d": np.concatenate([xy, np.ones((25, 1))], 1).reshape(-1).tolist()}],
        },
        "camera": cam.to_dict(),
        "mask": mask,
        "image": image,
        "model_bytes": Path(model_path).read_bytes(),
        "size": (160, 120),
    }


# ----------------------------------------------------------------------------- mutations
def _bytes_mutation(rng: random.Random, data: bytes) -> bytes:
    kind = rng.choice(["truncate", "flip", "random", "empty", "append", "utf16"])
    if kind == "truncate":
        return data[: rng.randrange(len(data) + 1)]
    if kind == "flip":
        b = bytearray(data)
        for _ in range(rng.randint(1, 8)):
            if b:
                b[rng.randrange(len(b))] = rng.randrange(256)
        return bytes(b)
    if kind == "random":
        return bytes(rng.randrange(256) for _ in range(rng.randint(1, 300)))
    if kind == "empty":
        return b""
    if kind == "append":
        return data + bytes(rng.randrange(256) for _ in range(rng.randint(1, 20)))
    try:
        return data.decode("utf-8").encode("utf-16")
    except UnicodeDecodeError:
        return data[::-1]


def mutate_keypoints(rng: random.Random, doc: dict, size, valid: dict) -> object:
    """``doc`` (OpenPose-like) changed once; ``valid`` is the unmutated document."""
    doc = json.loads(json.dumps(doc))
    values = doc["people"][0]["pose_keypoints_2d"]
    numeric = valid["people"][0]["pose_keypoints_2d"]
    kind = rng.choice(["junk", "junk", "length", "structure", "coco", "degenerate", "far", "people", "nested"])
    if kind == "junk":
        for _ in range(rng.randint(1, 5)):
            values[rng.randrange(len(values))] = rng.choice(JUNK)
    elif kind == "length":
        doc["people"][0]["pose_keypoints_2d"] = values[: rng.randrange(len(values) + 10)] * rng.choice([1, 2])
    elif kind == "structure":
        doc = rng.choice(
            [
                [],
                {},
                {"people": []},
                {"people": "x"},
                {"people": [1]},
                {"people": [{}]},
                "text",
                3,
                None,
                {"people": [{"pose_keypoints_2d": None}]},
                [values],
                {"keypoints": values[:51]},
            ]
        )
    elif kind == "coco":
        doc = {"keypoints": values[:51]} if rng.random() < 0.5 else [{"keypoints": values[:51]}, rng.choice(JUNK)]
    elif kind == "degenerate":
        arr = np.asarray(numeric, dtype=float).reshape(-1, 3)
        arr[:, :2] = arr[:, :2].mean(0) + (arr[:, :2] - arr[:, :2].mean(0)) * rng.choice([0.0, 1e-3, 0.05, 0.1])
        doc["people"][0]["pose_keypoints_2d"] = arr.reshape(-1).tolist()
    elif kind == "far":
        arr = np.asarray(numeric, dtype=float).reshape(-1, 3)
        idx = rng.sample(range(25), rng.randint(1, 25))
        arr[idx, :2] = rng.choice([1e30, -1e30, 1e6, 3 * max(size), -2 * max(size)])
        doc["people"][0]["pose_keypoints_2d"] = arr.reshape(-1).tolist()
    elif kind == "people":
        doc["people"] = doc["people"] * rng.randint(2, 4) + [rng.choice(JUNK)] * rng.randint(0, 1)
    else:
        doc["people"][0]["pose_keypoints_2d"] = [values[i : i + 3] for i in range(0, len(values), 3)]
        if rng.random() < 0.5:
            doc["people"][0]["pose_keypoints_2d"][rng.randrange(25)] = rng.choice(JUNK + [[1, 2], [1, 2, 3, 4]])
    return doc


def mutate_camera(rng: random.Random, cam: dict) -> object:
    cam = dict(cam)
    kind = rng.choice(["junk", "missing", "huge", "ratio", "structure"])
    if kind == "junk":
        cam[rng.choice(list(cam))] = rng.choice(JUNK)
    elif kind == "missing":
        cam.pop(rng.choice(list(cam)))
    elif kind == "huge":
        side = rng.choice([100000, 20000, 9000, 10**12])
        cam.update(width=side, height=side, cx=side / 2, cy=side / 2, fx=side, fy=side)
    elif kind == "ratio":
        cam[rng.choice(["fx", "fy", "cx", "cy"])] = rng.choice([1e-9, 1e9, -1e9, 0.0, -1.0, 1e300])
    else:
        return rng.choice([[], "camera", None, [cam], {"camera": cam}])
    return cam


def _encode_image(rng: random.Random, pixels: np.ndarray) -> bytes:
    from PIL import Image

    mode = rng.choice(["1", "L", "P", "RGB", "RGBA", "LA", "I", "I;16", "F", "CMYK"])
    fmt = rng.choice(["PNG", "PNG", "TIFF", "BMP", "JPEG"])
    img = Image.fromarray(pixels)
    try:
        img = img.convert(mode) if mode != "I;16" else Image.fromarray(pixels.astype(np.uint16) * 257)
        buf = io.BytesIO()
        img.save(buf, format=fmt)
    except (OSError, ValueError, KeyError, TypeError):  # a mode the format (or PIL) cannot hold
        buf = io.BytesIO()
        Image.fromarray(pixels).save(buf, format="PNG")
    return buf.getvalue()


def _png_header(width: int, height: int) -> bytes:
    import struct
    import zlib

    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    return (
        b"\x89PNG\r\n\x1a\n"
        + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0))
        + chunk(b"IEND", b"")
    )


def mutate_mask(rng: random.Random, mask: np.ndarray) -> bytes:
    kind = rng.choice(["mode", "size", "empty", "white", "noise", "colour", "header", "bytes"])
    if kind == "mode":
        return _encode_image(rng, mask)
    if kind == "size":
        return _encode_image(
            rng,
            mask[: rng.randint(1, mask.shape[0]), : rng.randint(1, mask.shape[1] + 40)]
            if rng.random() < 0.5
            else np.pad(mask, ((0, rng.randint(1, 9)), (0, 0))),
        )
    if kind in ("empty", "white"):
        return _encode_image(rng, np.full_like(mask, 0 if kind == "empty" else 255))
    if kind == "noise":
        return _encode_image(
            rng, (np.random.default_rng(rng.randrange(2**32)).random(mask.shape) > 0.5).astype(np.uint8) * 255
        )
    if kind == "colour":
        return _encode_image(rng, np.dstack([mask, mask // 2, np.zeros_like(mask)]))
    if kind == "header":
        return _png_header(*rng.choice([(100000, 100000), (20000, 10), (160, 120), (0, 0)]))
    return _bytes_mutation(rng, _encode_image(rng, mask))


def hostile_pickle(rng: random.Random, marker: Path) -> bytes:
    cmd = f"touch {marker}".encode()
    return rng.choice(
        [
            b"cos\nsystem\n(V" + cmd + b"\ntR.",
            b"cposix\nsystem\n(V" + cmd + b"\ntR.",
            b"c__builtin__\neval\n(V__import__('os').system('" + cmd + b"')\ntR.",
            b"\x80\x02csubprocess\nPopen\n]V" + cmd + b"\naR\x85R.",
            pickle.dumps({"means": np.zeros((1, 69)), "covars": np.eye(69)[None], "weights": np.ones(1)}, protocol=2),
        ]
    )


# ----------------------------------------------------------------------------- one case
def _openpose_like(doc) -> bool:
    try:
        return len(doc["people"][0]["pose_keypoints_2d"]) == 75
    except (KeyError, IndexError, TypeError):
        return False


def make_case(rng: random.Random, base: dict, d: Path) -> list:
    """Write one (mutated) input set into ``d``; the ``silfit fit`` arguments."""
    kp, cam = base["keypoints"], base["camera"]
    kp_bytes = cam_bytes = mask_bytes = image_bytes = None
    model_bytes, prior_bytes = base["model_bytes"], None
    extra = []
    targets = rng.sample(
        ["keypoints", "keypoints", "camera", "mask", "image", "model", "prior", "options", "bytes"], rng.randint(1, 3)
    )
    with_mask = rng.random() < 0.5 or "mask" in targets
    use_camera = rng.random() < 0.7 or "camera" in targets
    for t in targets:
        if t == "keypoints":
            kp = mutate_keypoints(rng, kp if _openpose_like(kp) else base["keypoints"], base["size"], base["keypoints"])
        elif t == "camera":
            cam = mutate_camera(rng, base["camera"])
        elif t == "mask":
            mask_bytes = mutate_mask(rng, base["mask"])
        elif t == "image":
            image_bytes = mutate_mask(rng, base["image"][..., 0])
        elif t == "model":
            model_bytes = (
                hostile_pickle(rng, d / "ran") if rng.random() < 0.3 else _bytes_mutation(rng, base["model_bytes"])
            )
        elif t == "prior":
            prior_bytes = (
                hostile_pickle(rng, d / "ran")
                if rng.random() < 0.6
                else _bytes_mutation(rng, hostile_pickle(rng, d / "ran"))
            )
        elif t == "options":
            flag = rng.choice(["--person", "--image-size", "--focal", "--silhouette-resolutions", "--gender"])
            value = {
                "--person": ["1", "-1", "x", "99", "0", "largest"],
                "--image-size": ["0x0", "100000x100000", "axb", "160x120", "-5x3", "160"],
                "--focal": ["nan", "inf", "-1", "0", "1e308", "160", "1e-9"],
                "--silhouette-resolutions": ["0", "64,64", "x", "64"],
                "--gender": ["male", "other", ""],
            }[flag]
            extra += [flag, rng.choice(value)]
            if flag == "--image-size":
                use_camera = False
        else:
            which = rng.choice(["keypoints", "camera"])
            if which == "keypoints":
                kp_bytes = _bytes_mutation(rng, json.dumps(kp).encode())
            else:
                cam_bytes = _bytes_mutation(rng, json.dumps(cam).encode())
    (d / "kp.json").write_bytes(kp_bytes if kp_bytes is not None else json.dumps(kp).encode())
    (d / "camera.json").write_bytes(cam_bytes if cam_bytes is not None else json.dumps(cam).encode())
    (d / "model.npz").write_bytes(model_bytes)
    args = [
        "fit",
        "--keypoints",
        str(d / "kp.json"),
        "--model",
        str(d / "model.npz"),
        "--out",
        str(d / "out"),
        "--quiet",
    ]
    if "--focal" in extra or not use_camera:
        if "--image-size" not in extra:
            args += ["--image", str(d / "image.png")]
            (d / "image.png").write_bytes(
                image_bytes if image_bytes is not None else _encode_image(rng, base["image"][..., 0])
            )
    else:
        args += ["--camera", str(d / "camera.json")]
    if with_mask:
        (d / "mask.png").write_bytes(
            mask_bytes if mask_bytes is not None else _encode_image(random.Random(0), base["mask"])
        )
        args += ["--mask", str(d / "mask.png")]
    if prior_bytes is not None:
        (d / "prior.pkl").write_bytes(prior_bytes)
        args += ["--pose-prior", str(d / "prior.pkl")]
    return args + extra


def run_case(argv: list, d: Path) -> tuple[str, str]:
    """``(outcome, detail)``: outcome is ``ok``, ``clean error`` or ``crash``."""
    from silfit.cli import main

    err, out = io.StringIO(), io.StringIO()
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out):
            rc = main(argv)
    except SystemExit as stop:  # argparse rejected an option value: its own usage + error lines
        return ("clean error", "argparse") if stop.code == 2 else ("crash", f"SystemExit {stop.code}")
    except BaseException as exc:  # noqa: BLE001 - this is what the fuzzer looks for
        return "crash", "".join(traceback.format_exception_only(type(exc), exc)).strip() + " @ " + traceback.extract_tb(
            exc.__traceback__
        )[-1].filename
    lines = [ln for ln in err.getvalue().splitlines() if ln.strip()]
    if (d / "ran").exists():
        return "crash", "a hostile pickle ran"
    if rc == 0:
        return "ok", ""
    if rc == 2 and len(lines) == 1 and lines[0].startswith("silfit fit: error: ") and not (d / "out").exists():
        return "clean error", lines[0]
    return "crash", f"exit {rc}: {err.getvalue().strip()[:300]}"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cases", type=int, default=10000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--fit-every", type=int, default=25, help="fit every N-th case that passes the checks (default 25)")
    ap.add_argument("--show", type=int, default=8, help="distinct crash messages to print (default 8)")
    args = ap.parse_args()
    import cv2
    import torch

    torch.set_num_threads(1)
    cv2.utils.logging.setLogLevel(
        cv2.utils.logging.LOG_LEVEL_SILENT
    )  # OpenCV's own decoder warnings on broken files (the errors are what is counted)
    rng = random.Random(args.seed)
    work = Path(tempfile.mkdtemp(prefix="silfit-fuzz-"))
    base = valid_inputs(work)
    counts, fits, crashes, errors = Counter(), Counter(), Counter(), Counter()
    passed = 0
    t0 = time.perf_counter()
    try:
        for i in range(args.cases):
            d = work / f"case{i % 4}"
            shutil.rmtree(d, ignore_errors=True)
            d.mkdir()
            argv = make_case(rng, base, d)
            outcome, detail = run_case(argv + ["--check-only"], d)
            counts[outcome] += 1
            if outcome == "crash":
                crashes[detail] += 1
            elif outcome == "clean error":
                errors[detail.split(": ")[-1][:60] if detail != "argparse" else "argparse"] += 1
            if outcome == "ok":
                passed += 1
                if passed % args.fit_every == 1 or args.fit_every == 1:
                    fit_argv = [a for a in argv if a != "--check-only"]
                    if "--mask" in fit_argv:
                        k = fit_argv.index("--mask")
                        del fit_argv[k : k + 2]
                    outcome, detail = run_case(fit_argv + ["--no-silhouette"], d)
                    fits[outcome] += 1
                    if outcome == "crash":
                        crashes["(fit) " + detail] += 1
            if (i + 1) % 1000 == 0:
                print(f"  {i + 1} cases, {time.perf_counter() - t0:.0f} s: {dict(counts)}", file=sys.stderr)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    seconds = time.perf_counter() - t0
    print(f"## silfit fit fuzzing: {args.cases} cases, seed {args.seed}, {seconds:.0f} s\n")
    print("| path | cases | ok | clean error | crash |\n|---|---:|---:|---:|---:|")
    print(
        f"| readers + checks (`--check-only`) | {sum(counts.values())} | {counts['ok']} | {counts['clean error']} | {counts['crash']} |"
    )
    print(
        f"| keypoint fit + output (`--no-silhouette`) | {sum(fits.values())} | {fits['ok']} | {fits['clean error']} | {fits['crash']} |"
    )
    print("\nmost common clean errors:")
    for message, n in errors.most_common(12):
        print(f"  {n:5d}  {message}")
    if crashes:
        print("\ncrashes:")
        for message, n in crashes.most_common(args.show):
            print(f"  {n:5d}  {message}")
    return 1 if crashes else 0


if __name__ == "__main__":
    sys.exit(main())
