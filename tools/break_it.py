"""Break the fitter on purpose and report which breakages the test suite catches.

Each breakage is a small text patch applied to a temporary copy of the repository
(nothing in this tree changes); the relevant test files then run in that copy
(``PYTHONPATH`` pointing at it). A breakage is *caught* when pytest fails. Before the
breakages, the same test files run on the unpatched copy: a file that already fails
there would make every breakage look caught, so the script stops.

    python tools/break_it.py                 # every breakage, a Markdown table
    python tools/break_it.py --only l2,flip  # some of them (names in the table)
    python tools/break_it.py --list

A patch whose text is no longer in the source is reported as ``patch stale`` (the code
moved: update the patch), never silently skipped.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence, Tuple

ROOT = Path(__file__).resolve().parents[1]


@dataclass(frozen=True)
class Breakage:
    name: str
    what: str
    #: (file, old text, new text); the old text must occur exactly once
    patches: Tuple[Tuple[str, str, str], ...]
    tests: Tuple[str, ...]  # test node ids or files run against the broken copy


SIL = "silfit/fitting/silhouette_stage.py"
OPTIM = "silfit/fitting/optim.py"
TERMS = "silfit/fitting/terms.py"
KP = "silfit/fitting/keypoint_stage.py"
TRI = "silfit/fitting/triangulate.py"
SCHED = "silfit/fitting/schedules.py"

BREAKAGES = (
    Breakage(
        "translation_only",
        "silhouette stage optimises the translation only (its free parameters, free_names in _fit_problems)",
        (
            (
                SIL,
                "free_names = tuple(n for n in cfg.optimise if n in params_layout.sizes)",
                'free_names = tuple(n for n in cfg.optimise if n in params_layout.sizes and n == "transl")',
            ),
        ),
        ("tests/fitting/test_recovery.py::test_silhouette_stage_recovers_the_truth",),
    ),
    Breakage(
        "shared_step",
        "L-BFGS line search shares one step length across the batch (samples coupled)",
        (
            (
                OPTIM,
                "ok = torch.isfinite(ft) & (ft <= fa[todo] + c1 * t[todo] * gtd[todo])",
                "ok = torch.isfinite(ft) & (ft <= fa[todo] + c1 * t[todo] * gtd[todo])\n            ok = ok & bool(ok.all())",
            ),
            (
                OPTIM,
                "t[rej] = torch.minimum(torch.maximum(tq, 0.1 * tr), 0.5 * tr)",
                "t[rej] = torch.minimum(torch.maximum(tq, 0.1 * tr), 0.5 * tr)\n            t[:] = t[rej].min()",
            ),
        ),
        ("tests/fitting/test_optim_losses.py", "tests/fitting/test_keypoint_stage.py::test_batch_equals_single_fits"),
    ),
    Breakage(
        "l2",
        "robust (Geman-McClure) keypoint term replaced by plain L2 (KeypointTerm's constructor drops sigma)",
        (
            (
                TERMS,
                "self.name, self.sigma, self.mask, self.weights_key = name, sigma, mask, weights_key",
                "self.name, self.sigma, self.mask, self.weights_key = name, None, mask, weights_key",
            ),
        ),
        (
            "tests/fitting/test_keypoint_stage.py::test_outlier_moves_the_robust_fit_far_less_than_l2",
            "tests/fitting/test_terms.py",
        ),
    ),
    Breakage(
        "interpenetration_zero",
        "interpenetration penalty returns zero",
        (
            (
                "silfit/priors/interpenetration.py",
                "index_add(0, row, overlap * overlap)",
                "index_add(0, row, 0.0 * overlap)",
            ),
        ),
        ("tests/priors/test_interpenetration.py",),
    ),
    Breakage(
        "interpenetration_term_zero",
        "the fit's interpenetration term returns zero (the prior itself intact)",
        (
            (
                TERMS,
                'return ev.per_problem(self.collisions(ev.rows["betas"], ev.body.transforms))',
                'return ev.per_problem(0.0 * self.collisions(ev.rows["betas"], ev.body.transforms))',
            ),
        ),
        ("tests/fitting/test_terms.py",),
    ),
    Breakage(
        "dt_swapped",
        "distance transforms swapped inside/outside",
        (
            (
                "silfit/silhouette/losses.py",
                "return outside.astype(np.float32), inside.astype(np.float32)",
                "return inside.astype(np.float32), outside.astype(np.float32)",
            ),
        ),
        ("tests/silhouette/test_losses.py",),
    ),
    Breakage(
        "confidence_ignored",
        "keypoint confidences ignored (every visible keypoint weighted 1, in KeypointFitter._problem_data)",
        (
            (
                KP,
                "weights.append([[o.keypoints.conf for o in row] for row in grid])",
                "weights.append([[(o.keypoints.conf > 0).astype(float) for o in row] for row in grid])",
            ),
        ),
        ("tests/fitting/test_keypoint_stage.py::test_low_confidence_keypoints_count_less",),
    ),
    Breakage(
        "flip_off",
        "flip test off by default (Starts.flip = False, once KeypointFitConfig.flip_test)",
        ((KP, "flip: bool = True", "flip: bool = False"),),
        ("tests/fitting/test_keypoint_stage.py::test_back_facing_subject_is_fitted_facing_away",),
    ),
    # issue 22: breakages that passed every behaviour test before these tests (each runs only its new test)
    Breakage(
        "temporal_off",
        "sequence refinement's temporal smoothness terms off (SEQUENCE_SCHEDULE's smooth_joints and smooth_root "
        "weights 0, so SequenceFitConfig.joint_smooth_weight and root_smooth_weight default to 0)",
        (
            (SCHED, '"smooth_joints": 1.0,', '"smooth_joints": 0.0,'),
            (SCHED, '"smooth_root": 1.0,', '"smooth_root": 0.0,'),
        ),
        ("tests/fitting/test_sequence.py::test_temporal_terms_smooth_a_noisy_sequence",),
    ),
    Breakage(
        "dlt_unweighted",
        "triangulation (DLT) ignores the confidences (every seeing view weighted 1)",
        ((TRI, "w = np.asarray(weights, np.float64)", "w = (np.asarray(weights, np.float64) > 0).astype(np.float64)"),),
        ("tests/fitting/test_triangulate.py::test_dlt_trusts_the_confident_views",),
    ),
    Breakage(
        "interpenetration_off",
        "interpenetration off in the keypoint stage (KEYPOINT_SCHEDULE's interpenetration weights 0: the FINAL rows' "
        "and branches_1's, so KeypointFitConfig.interpenetration_weight defaults to 0)",
        (
            (SCHED, '"interpenetration": 1e5,', '"interpenetration": 0.0,'),
            (SCHED, '"interpenetration": 1e5}', '"interpenetration": 0.0}'),
        ),
        ("tests/fitting/test_keypoint_stage.py::test_self_contact_poses_are_fitted_without_the_arms_inside_the_body",),
    ),
    Breakage(
        "camera_depth_nothing",
        "the camera stage's depth term scaled to nothing (KEYPOINT_SCHEDULE's camera row: weight x 1e-9)",
        ((SCHED, '{"torso": 1.0, "depth": 1e3}', '{"torso": 1.0, "depth": 1e-9 * 1e3}'),),
        ("tests/fitting/test_keypoint_stage.py::test_camera_stage_keeps_the_root_near_the_similar_triangles_depth",),
    ),
    Breakage(
        "shape_prior_zero",
        "the shape prior returns 0",
        (("silfit/priors/simple.py", "return (betas * betas).sum(-1)", "return 0.0 * (betas * betas).sum(-1)"),),
        ("tests/fitting/test_keypoint_stage.py::test_shape_prior_keeps_the_shape_bounded_on_noisy_keypoints",),
    ),
)


def copy_tree(dst: Path) -> None:
    ignore = shutil.ignore_patterns(".git", ".venv", "__pycache__", ".pytest_cache", "*.egg-info", "out", "runs")
    shutil.copytree(ROOT, dst, ignore=ignore, symlinks=True)


def apply(root: Path, patches) -> str:
    """Apply the patches in ``root``; returns '' or why one could not be applied."""
    for rel, old, new in patches:
        path = root / rel
        text = path.read_text()
        n = text.count(old)
        if n != 1:
            return f"patch stale: {rel} has {n} copies of {old[:50]!r}"
        path.write_text(text.replace(old, new))
    return ""


def run_pytest(root: Path, tests: Sequence[str], timeout: float) -> Tuple[int, str, float]:
    env = dict(os.environ, PYTHONPATH=str(root), PYTHONDONTWRITEBYTECODE="1")
    cmd = [
        sys.executable,
        "-m",
        "pytest",
        "-q",
        "-x",
        "-n",
        "0",
        "-p",
        "no:cacheprovider",
        *tests,
    ]  # a few tests: one process
    t0 = time.perf_counter()
    try:
        p = subprocess.run(cmd, cwd=root, env=env, capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return -1, "timeout", time.perf_counter() - t0
    lines = [ln for ln in p.stdout.strip().splitlines() if ln.strip()]
    return p.returncode, (lines[-1] if lines else p.stderr.strip()[-200:]), time.perf_counter() - t0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", help="comma-separated breakage names")
    ap.add_argument("--list", action="store_true", help="list the breakages and exit")
    ap.add_argument("--timeout", type=float, default=900.0, help="seconds per pytest run")
    ap.add_argument("--no-baseline", action="store_true", help="skip the run on the unpatched copy")
    args = ap.parse_args(argv)
    chosen = BREAKAGES
    if args.only:
        names = args.only.split(",")
        unknown = sorted(set(names) - {b.name for b in BREAKAGES})
        if unknown:
            print(f"--only: unknown breakage(s) {', '.join(unknown)}", file=sys.stderr)
            return 2
        chosen = tuple(b for b in BREAKAGES if b.name in names)
    if args.list:
        for b in chosen:
            print(f"{b.name}: {b.what}\n    tests: {' '.join(b.tests)}")
        return 0
    with tempfile.TemporaryDirectory(prefix="silfit-break-") as tmp:
        if not args.no_baseline:
            base = Path(tmp) / "baseline"
            copy_tree(base)
            tests = sorted({t for b in chosen for t in b.tests})
            rc, last, secs = run_pytest(base, tests, args.timeout)
            print(f"baseline (unpatched copy): {last} ({secs:.0f} s)", flush=True)
            if rc != 0:
                print("the chosen tests fail without any breakage; fix them first", file=sys.stderr)
                return 1
        rows = []
        for b in chosen:
            work = Path(tmp) / b.name
            copy_tree(work)
            why = apply(work, b.patches)
            if why:
                rows.append((b, "NOT RUN", why, 0.0))
            else:
                rc, last, secs = run_pytest(work, b.tests, args.timeout)
                rows.append((b, "caught" if rc != 0 else "NOT CAUGHT", last, secs))
            print(f"{b.name}: {rows[-1][1]} ({rows[-1][3]:.0f} s)", flush=True)
            shutil.rmtree(work, ignore_errors=True)
    print("\n| breakage | what | result | tests run | pytest says |\n|---|---|---|---|---|")
    for b, result, last, _ in rows:
        tests = ", ".join(f"`{t.replace('tests/', '')}`" for t in b.tests)
        print(f"| {b.name} | {b.what} | **{result}** | {tests} | {last} |")
    caught = sum(r[1] == "caught" for r in rows)
    print(f"\n{caught} of {len(rows)} breakages caught")
    return 0 if caught == len(rows) else 1


if __name__ == "__main__":
    sys.exit(main())
