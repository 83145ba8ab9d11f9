"""Renderer benchmark: Mitsuba silhouettes (forward, forward+backward) and pyrender.

Prints a Markdown table of median warm times for the open body model (13,348 vertices)
upright at 2.8 m: Mitsuba silhouettes at 128/256/512 px with 1/4/16 primal samples per
pixel (edge samples ``sppp = 1``), the ROI mode (a 256x256 window around the person in a
1024x1024 image), and pyrender colour + mask at 512x512.  Forward+backward includes the
torch bridge and a squared-error loss against a fixed target.

    .venv/bin/python benchmarks/bench_render.py [--repeats 7] [--sizes 128,256,512] [--spp 1,4,16]

Targets on the 2-core CPU: forward+backward 256x256 at 4 spp <= 110 ms; pyrender colour
+ mask 512x512 <= 30 ms.
"""
from __future__ import annotations

import argparse
import math
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import torch  # noqa: E402

TARGETS = {("fwd+bwd", 256, 4): 110.0, ("pyrender", 512, None): 30.0}


def median_ms(fn, repeats: int, warmup: int = 2) -> float:
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        times.append((time.perf_counter() - t) * 1000.0)
    return statistics.median(times)


def body_vertices():
    import silfit

    model = silfit.load_body_model()
    with torch.no_grad():
        out = model(global_orient=torch.tensor([[math.pi, 0.0, 0.0]]), transl=torch.tensor([[0.0, -0.2, 2.8]]))
    return out.vertices[0].float(), model.faces


def camera_for(size: int):
    from silfit.camera import Camera

    f = 1.1 * size  # the body fills ~70 % of the image height
    return Camera(fx=f, fy=f, cx=(size - 1) / 2, cy=(size - 1) / 2, width=size, height=size)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--sizes", default="128,256,512")
    ap.add_argument("--spp", default="1,4,16")
    args = ap.parse_args(argv)
    sizes = [int(s) for s in args.sizes.split(",")]
    spps = [int(s) for s in args.spp.split(",")]

    from renderers import SilhouetteRenderer, render_mesh
    from renderers.silhouette import roi_window

    verts, faces = body_vertices()
    renderer = SilhouetteRenderer(faces, edge_spp=1)
    rows = []

    def bench_mitsuba(camera, spp, label, window=None):
        with torch.no_grad():
            target = (renderer(verts + torch.tensor([0.02, 0.01, 0.0]), camera, spp=16, seed=0) > 0.5).float()

        def fwd():
            with torch.no_grad():
                renderer(verts, camera, spp=spp)

        def fwd_bwd():
            v = verts.clone().requires_grad_()
            s = renderer(v, camera, spp=spp)
            ((s - target) ** 2).sum().backward()

        t_f = median_ms(fwd, args.repeats)
        t_fb = median_ms(fwd_bwd, args.repeats)
        rows.append((label, f"{camera.width}x{camera.height}", spp, t_f, t_fb))

    for size in sizes:
        for spp in spps:
            bench_mitsuba(camera_for(size), spp, "Mitsuba silhouette")
    big = camera_for(1024)
    window = roi_window(verts, big, size=256)
    bench_mitsuba(window.camera, 4, f"Mitsuba ROI (1024x1024 image, scale {window.scale:.2f})")

    cam512 = camera_for(512)

    def pyr():
        r = render_mesh(verts, faces, cam512)
        return r.color, r.mask

    t_p = median_ms(pyr, args.repeats)
    rows.append(("pyrender colour+mask", "512x512", None, t_p, None))

    print(f"Variant: {renderer.variant}; torch threads {torch.get_num_threads()}; median of {args.repeats} warm runs.\n")
    print("| renderer | size | spp | forward (ms) | forward+backward (ms) |")
    print("|---|---|---|---|---|")
    ok = True
    for label, size, spp, t_f, t_fb in rows:
        spp_s = "-" if spp is None else str(spp)
        fb_s = "-" if t_fb is None else f"{t_fb:.1f}"
        print(f"| {label} | {size} | {spp_s} | {t_f:.1f} | {fb_s} |")
    fb256 = next((r[4] for r in rows if r[1] == "256x256" and r[2] == 4 and r[0] == "Mitsuba silhouette"), None)
    print()
    if fb256 is not None:
        good = fb256 <= 110.0
        ok &= good
        print(f"target forward+backward 256x256 4 spp <= 110 ms: {fb256:.1f} ms {'OK' if good else 'MISSED'}")
    good = t_p <= 30.0
    ok &= good
    print(f"target pyrender colour+mask 512x512 <= 30 ms: {t_p:.1f} ms {'OK' if good else 'MISSED'}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
