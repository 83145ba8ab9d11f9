"""Same inputs, same fit: the silhouette stage's contour level gives bit-identical results
from one process to the next, and whatever else the process allocated before it.

The cause it guards against: OpenCV's IPP path of the precise distance transform rounds by
the output buffer's address (1-2 ulp), so the same target mask gave other distances, and
L-BFGS other fits, with the heap's state (a batch of subjects more often than one)."""

import json
import os
import subprocess
import sys
import textwrap

import numpy as np
from silfit.fitting.keypoint_stage import BranchSearch, Starts

# A child fits the contour level on a batch of 3 (160 px images, 64 px window, 6 iterations) ``REPEATS``
# times, each after keeping a differently sized allocation alive (the heap's state differs,
# so the buffers the fit allocates land elsewhere), and prints every result.
CHILD = textwrap.dedent("""
    import silfit  # first: the pinned kernels (silfit.kernels)
    import json, math, sys
    import numpy as np, torch
    from silfit.render.offscreen import render_mask
    from silfit.body import load_body_model
    from silfit.camera import Camera
    from silfit.fitting.silhouette_stage import SilhouetteFitConfig, fit_silhouettes

    model = load_body_model()
    cam = Camera.from_image_size(160, 160)
    pose = {"betas": np.zeros((1, 10), np.float32), "body_pose": np.zeros((1, 69), np.float32),
            "global_orient": np.array([[math.pi, 0.0, 0.0]], np.float32), "transl": np.array([[0.0, 0.15, 3.0]], np.float32)}
    masks = []
    for dx, db in ((0.08, 0.0), (-0.05, 0.5), (0.03, -0.4)):
        p = {k: torch.as_tensor(v) for k, v in pose.items()}
        p["transl"] = p["transl"] + torch.tensor([[dx, 0.02, 0.0]])
        p["betas"] = torch.full((1, 10), db)
        p["body_pose"] = torch.zeros(1, 69)
        p["body_pose"][0, 47] = -0.6  # a bent elbow
        with torch.no_grad():
            masks.append(render_mask(model(**p).vertices[0].numpy(), model.faces.numpy(), cam))
    cfg = SilhouetteFitConfig(resolutions=(48,), iterations=(0,), contour_iterations=6, contour_resolution=64,
                              contour_vertices=800, w_keypoints=0.0)
    kept, out = [], []
    for k in range(int(sys.argv[2])):
        kept.append(np.ones(16384 + 16 * (int(sys.argv[1]) + 3 * k) + 8, np.uint8))
        rs = fit_silhouettes(model, [pose] * 3, [cam] * 3, masks, config=cfg, progress=False)
        out.append([{k: v.tolist() for k, v in r.parameters.items()} for r in rs])
    print("RESULT " + json.dumps(out))
""")
REPEATS = 3


def run_child(hash_seed: int, shift: int) -> list:
    root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    env = dict(
        os.environ,
        PYTHONHASHSEED=str(hash_seed),
        PYTHONPATH=os.pathsep.join(filter(None, [root, os.environ.get("PYTHONPATH")])),
    )
    done = subprocess.run(
        [sys.executable, "-c", CHILD, str(shift), str(REPEATS)],
        env=env,
        cwd=root,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    line = [s for s in done.stdout.splitlines() if s.startswith("RESULT ")][-1]
    return json.loads(line[len("RESULT ") :])


def test_contour_level_of_a_batch_is_bit_identical_across_processes():
    runs = run_child(0, 0) + run_child(1, 1)  # 2 processes x REPEATS fits, other hash seeds and heaps
    first = runs[0]
    for i, run in enumerate(runs[1:], 1):
        for p, (a, b) in enumerate(zip(first, run)):
            for name in a:
                assert np.array_equal(np.asarray(a[name], np.float32), np.asarray(b[name], np.float32)), (
                    f"fit {i}, subject {p}: {name} differs from the first fit's"
                )


def test_distance_transforms_do_not_depend_on_the_buffers_address(monkeypatch):
    """The root cause directly: the same mask through OpenCV with its output buffer at
    other addresses (offsets of 0-7 floats from a 64-byte boundary) gives the same distances."""
    import cv2

    from silfit.silhouette.losses import distance_transforms

    yy, xx = np.mgrid[:61, :47]
    mask = ((xx - 22.3) / 14.1) ** 2 + ((yy - 30.2) / 23.7) ** 2 < 1
    valid = np.ones_like(mask)
    valid[:, :3] = False
    original = cv2.distanceTransform
    results = []
    for offset in range(8):

        def at_offset(src, *args, offset=offset, **kwargs):
            n = src.size * 4
            buf = np.zeros(n + 128, np.uint8)
            base = (-buf.ctypes.data) % 64 + 4 * offset
            return original(src, *args, dst=buf[base : base + n].view(np.float32).reshape(src.shape), **kwargs)

        monkeypatch.setattr(cv2, "distanceTransform", at_offset)
        results.append(distance_transforms(mask, valid))
    monkeypatch.setattr(cv2, "distanceTransform", original)
    for outside, inside in results[1:]:
        assert np.array_equal(outside, results[0][0]) and np.array_equal(inside, results[0][1])
    # and they are the exact Euclidean distances (squares of integers' roots), to float32 rounding
    assert abs(float(results[0][0].max()) - float(np.sqrt(np.round(results[0][0].max() ** 2)))) < 1e-5


# A child fits the third shipped subject (float64, a short schedule) and prints the parameters.
KEYPOINT_CHILD = textwrap.dedent("""
    import silfit  # first: the pinned kernels (silfit.kernels)
    import json, sys
    import numpy as np, torch
    from silfit import load_body_model
    from silfit.io.subjects import list_subjects, load_subject
    from silfit.fitting import BranchSearch, KeypointFitConfig, Starts
    from silfit.fitting.keypoint_stage import fit_keypoints

    s = load_subject(list_subjects(sys.argv[1])[2])
    cfg = KeypointFitConfig(camera_iters=8, pose_iters=(8, 8, 8), shape_iters=5, final_iters=8,
                            starts=Starts(poses=2), decision_iters=5,
                            branches=BranchSearch(iters=6, screen_iters=4))
    r = fit_keypoints(s.keypoints, s.camera, load_body_model(dtype=torch.float64), config=cfg, progress=False)
    print("RESULT " + json.dumps({k: np.asarray(v, np.float64).tolist() for k, v in r.params(0).items()}))
""")


def test_a_keypoint_fit_is_the_same_bits_with_one_or_two_threads_and_either_mkl_branch(tmp_path):
    """No BLAS in the body model and the keypoint stage (silfit.body.lbs): on an Intel Xeon MKL's
    GEMMs gave another float64 fit with one thread than with two (1.1 mm), so the reference fits
    failed there. Each setting in its own process (the libraries read these once)."""
    root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    results = []
    for threads, branch in (("2", "AVX2"), ("1", "AVX2"), ("1", "COMPATIBLE")):
        # MKL's AVX2 branch (whose GEMMs followed the thread count there, where COMPATIBLE's did not), then its
        # COMPATIBLE one (whose GEMMs rounded the collision spheres' posed vertices otherwise: 1.1 mm on an Intel
        # Xeon against an AMD EPYC), and a cache of its own, so each child builds the collision spheres itself
        env = dict(
            os.environ,
            OMP_NUM_THREADS=threads,
            MKL_NUM_THREADS=threads,
            MKL_CBWR=branch,
            SILFIT_CACHE_DIR=str(tmp_path / f"cache{threads}{branch}"),
            PYTHONPATH=os.pathsep.join(filter(None, [root, os.environ.get("PYTHONPATH")])),
        )
        done = subprocess.run(
            [sys.executable, "-c", KEYPOINT_CHILD, os.path.join(root, "data", "synthetic")],
            env=env,
            cwd=root,
            capture_output=True,
            text=True,
            timeout=300,
        )
        assert done.returncode == 0, done.stderr[-3000:]
        results.append(
            json.loads([s for s in done.stdout.splitlines() if s.startswith("RESULT ")][-1][len("RESULT ") :])
        )
    assert results[0] == results[1] == results[2]
    assert abs(results[0]["transl"][-1]) > 1.0  # a fitted body in front of the camera


#: kernels whose results follow the processor although silfit pins torch's SIMD level (silfit.kernels): BLAS
#: (MKL's GEMMs and matrix-vector products: another rounding on an Intel Xeon with AVX-512) and MKL's vector
#: square root (``torch.sqrt``, and ``pow(x, 0.5)`` which torch sends to it: not correctly rounded, and rounded
#: otherwise there). silfit.body.lbs's ``matmul``, ``sparse_contract`` and ``sqrt`` replace them.
PROCESSOR_DEPENDENT = {
    "aten.mm",
    "aten.bmm",
    "aten.addmm",
    "aten.baddbmm",
    "aten.addbmm",
    "aten.mv",
    "aten.addmv",
    "aten.dot",
    "aten.vdot",
    "aten.sqrt",
}


class _ProcessorDependentCalls:
    """A dispatch mode recording each processor-dependent kernel call with the silfit line it came from."""

    def __new__(cls):
        import traceback

        from torch.utils._python_dispatch import TorchDispatchMode

        class Mode(TorchDispatchMode):
            calls: list = []

            def __torch_dispatch__(self, func, types, args=(), kwargs=None):
                name = str(func).rsplit(".", 1)[0]
                half = name == "aten.pow" and len(args) > 1 and not hasattr(args[1], "shape") and args[1] == 0.5
                if name in PROCESSOR_DEPENDENT or half:
                    site = [
                        f"{f.filename.rsplit('silfit/', 1)[-1]}:{f.name}"
                        for f in traceback.extract_stack()
                        if "/silfit/" in f.filename
                    ]
                    self.calls.append((str(func), site))
                return func(*args, **(kwargs or {}))

        return Mode()


def test_the_keypoint_fit_and_its_collision_spheres_call_no_processor_dependent_kernel():
    """The float64 reference fits differed by 1.1 and 2.0 mm on an Intel Xeon with AVX-512 (issue 56):
    ``../shared/tools/op_trace.py`` found the first differing operation in the collision spheres' radius
    scales (the posed vertices they are calibrated on were a GEMM), and ``torch.sqrt`` rounds otherwise there.
    Neither may run on the fitting path: the fit's energies and steps, and the spheres' construction."""
    import torch

    from silfit import load_body_model
    from silfit.io.subjects import list_subjects, load_subject
    from silfit.fitting import KeypointFitConfig
    from silfit.fitting.keypoint_stage import fit_keypoints
    from silfit.priors.interpenetration import _mean_shape_posed, calibration_poses

    root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    model = load_body_model(dtype=torch.float64)
    s = load_subject(list_subjects(os.path.join(root, "data", "synthetic"))[1])
    cfg = KeypointFitConfig(
        camera_iters=3,
        pose_iters=(3, 3, 3),
        shape_iters=2,
        final_iters=3,
        decision_iters=2,
        starts=Starts(poses=2),
        branches=BranchSearch(iters=2, screen_iters=2, post_iters=2),
    )
    fit_keypoints(s.keypoints, s.camera, model, config=cfg, progress=False)  # the spheres built or read first
    mode = _ProcessorDependentCalls()
    with mode:
        fit_keypoints(s.keypoints, s.camera, model, config=cfg, progress=False)
        _mean_shape_posed(model, torch.as_tensor(calibration_poses()[:3, : model.num_body_pose]))
    # the only GEMM left skins whole meshes outside the energy: the fitted result's vertices and, once at set-up, the
    # rest pose (whose pelvis is read from the joints, which no skinning touches)
    outside = ("keypoint_stage.py:_result", "keypoint_stage.py:_setup")
    assert [c for c in mode.calls if not any(f.endswith(outside) for f in c[1])] == []
    assert all(c[0] == "aten.bmm.default" for c in mode.calls)
