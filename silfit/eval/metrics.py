"""Error metrics between a fitted body and the ground truth (numpy, metres in, metres out).

Conventions (as in the SMPLify / SPIN / HMR literature):

* **MPJPE**: mean Euclidean error over the model's joints (all 24 SMPL joints by default)
  after subtracting each set's pelvis (joint 0): pelvis-aligned.
* **PA-MPJPE**: mean joint error after a similarity Procrustes alignment (scale, rotation,
  translation) of the prediction onto the ground truth.
* **PVE**: mean per-vertex error of the posed meshes, pelvis-aligned like MPJPE
  (``pve(..., align=False)`` gives the raw camera-frame error).
* **Shape PVE**: PVE of the T-posed bodies (``model.rest_vertices(betas)``, zero pose), each
  centred on its own rest pelvis: the shape error with pose and placement removed.
* **Translation error**: distance between the two pelvis joints in camera coordinates
  (the placement error: depth dominates it).
* **Reprojection error**: mean 2D distance in pixels over the keypoints that are marked valid.
* **IoU**: ``|A and B| / |A or B|`` of two binary masks.
* **Acceleration error** (sequences, the jitter metric): mean over frames and joints of
  ``|a_pred - a_gt|`` with ``a`` the second difference over frames of the pelvis-aligned
  joints (metres per frame^2; ``root=None``: of the raw positions).

Every function takes arrays ``[..., N, 3]`` (a leading batch is allowed) and returns a
float (or ``[...]`` array for batched input).
"""

from __future__ import annotations

from typing import Optional, Tuple

import numpy as np

__all__ = [
    "procrustes_align",
    "mpjpe",
    "pa_mpjpe",
    "pve",
    "shape_pve",
    "translation_error",
    "reprojection_error",
    "mask_iou",
    "acceleration_error",
]


def _pair(pred, gt) -> Tuple[np.ndarray, np.ndarray]:
    pred = np.asarray(pred, dtype=np.float64)
    gt = np.asarray(gt, dtype=np.float64)
    if pred.shape != gt.shape:
        raise ValueError(f"prediction has shape {pred.shape}, ground truth {gt.shape}")
    if pred.ndim < 2 or pred.shape[-1] not in (2, 3):
        raise ValueError(f"expected points [..., N, 3] (or 2), got {pred.shape}")
    return pred, gt


def _out(x: np.ndarray):
    return float(x) if np.ndim(x) == 0 else x


def procrustes_align(pred, gt, scale: bool = True) -> np.ndarray:
    """``pred`` mapped onto ``gt`` by the similarity (or rigid, ``scale=False``) transform that
    minimises the summed squared distance (Umeyama 1991; reflections excluded)."""
    pred, gt = _pair(pred, gt)
    mu_p = pred.mean(-2, keepdims=True)
    mu_g = gt.mean(-2, keepdims=True)
    X, Y = pred - mu_p, gt - mu_g
    cov = np.swapaxes(X, -1, -2) @ Y  # [..., 3, 3]
    U, S, Vt = np.linalg.svd(cov)
    d = np.sign(np.linalg.det(U @ Vt))
    dim = pred.shape[-1]
    E = np.broadcast_to(np.eye(dim), cov.shape).copy()
    E[..., -1, -1] = d
    R = U @ E @ Vt  # X @ R ~ Y
    if scale:
        var = (X**2).sum((-1, -2))
        s = (S * np.diagonal(E, axis1=-2, axis2=-1)).sum(-1) / np.maximum(var, 1e-300)
    else:
        s = np.ones(pred.shape[:-2])
    return s[..., None, None] * (X @ R) + mu_g


def mpjpe(pred, gt, root: Optional[int] = 0) -> float:
    """Mean per-joint position error, aligned at joint ``root`` (``None``: no alignment)."""
    pred, gt = _pair(pred, gt)
    if root is not None:
        pred = pred - pred[..., root : root + 1, :]
        gt = gt - gt[..., root : root + 1, :]
    return _out(np.linalg.norm(pred - gt, axis=-1).mean(-1))


def pa_mpjpe(pred, gt) -> float:
    """MPJPE after similarity Procrustes alignment."""
    pred, gt = _pair(pred, gt)
    return _out(np.linalg.norm(procrustes_align(pred, gt) - gt, axis=-1).mean(-1))


def pa_pve(pred_vertices, gt_vertices) -> float:
    """Mean per-vertex error after similarity Procrustes alignment of the meshes."""
    pred, gt = _pair(pred_vertices, gt_vertices)
    return _out(np.linalg.norm(procrustes_align(pred, gt) - gt, axis=-1).mean(-1))


def pve(pred_vertices, gt_vertices, pred_root=None, gt_root=None, align: bool = True) -> float:
    """Mean per-vertex error. With ``align`` each mesh is shifted so that its root (``pred_root``
    / ``gt_root``, e.g. the pelvis joint, ``[..., 3]``; default: the vertex centroid) is at the
    origin."""
    pred, gt = _pair(pred_vertices, gt_vertices)
    if align:
        pr = pred.mean(-2) if pred_root is None else np.asarray(pred_root, dtype=np.float64)
        gr = gt.mean(-2) if gt_root is None else np.asarray(gt_root, dtype=np.float64)
        pred = pred - pr[..., None, :]
        gt = gt - gr[..., None, :]
    return _out(np.linalg.norm(pred - gt, axis=-1).mean(-1))


def shape_pve(model, pred_betas, gt_betas, scale: bool = False) -> float:
    """PVE of the T-posed (zero-pose) bodies of two shapes, each centred on its rest pelvis.

    With ``scale`` the predicted body is first scaled uniformly about its pelvis to fit the
    true one (least squares): what is left is the error of the body's proportions and
    build, without its stature, which one image cannot tell apart from distance."""
    import torch  # lazy: silfit.eval and its metrics import with numpy only (evaluate, the rest, is lazy)

    def rest(betas):
        b = torch.as_tensor(np.asarray(betas, dtype=np.float64), dtype=model.dtype, device=model.device)
        if b.ndim == 1:
            b = b[None]
        with torch.no_grad():
            out = model(betas=b)
        return out.vertices.cpu().double().numpy(), out.joints[:, 0].cpu().double().numpy()

    pb = np.asarray(pred_betas, dtype=np.float64)
    gb = np.asarray(gt_betas, dtype=np.float64)
    n = max(pb.shape[-1], gb.shape[-1])
    pb = np.pad(pb, [(0, 0)] * (pb.ndim - 1) + [(0, n - pb.shape[-1])])
    gb = np.pad(gb, [(0, 0)] * (gb.ndim - 1) + [(0, n - gb.shape[-1])])
    pv, pj = rest(pb)
    gv, gj = rest(gb)
    if scale:
        pc, gc = pv - pj[:, None], gv - gj[:, None]
        s = (pc * gc).sum(axis=(1, 2)) / np.maximum((pc * pc).sum(axis=(1, 2)), 1e-12)
        pv = pj[:, None] + s[:, None, None] * pc
    err = pve(pv, gv, pj, gj, align=True)
    return float(np.asarray(err).reshape(-1)[0]) if np.ndim(pred_betas) == 1 else err


def translation_error(pred_root, gt_root) -> float:
    """Euclidean distance between two root (pelvis) positions ``[..., 3]``."""
    p = np.asarray(pred_root, dtype=np.float64)
    g = np.asarray(gt_root, dtype=np.float64)
    if p.shape != g.shape:
        raise ValueError(f"prediction has shape {p.shape}, ground truth {g.shape}")
    return _out(np.linalg.norm(p - g, axis=-1))


def reprojection_error(pred_2d, gt_2d, valid=None) -> float:
    """Mean pixel distance ``[..., K, 2]`` over the keypoints where ``valid`` (bool or weights
    ``[..., K]``) is true; NaN when none is."""
    pred, gt = _pair(pred_2d, gt_2d)
    d = np.linalg.norm(pred - gt, axis=-1)
    if valid is None:
        return _out(d.mean(-1))
    w = np.asarray(valid, dtype=np.float64)
    total = w.sum(-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return _out(np.where(total > 0, (d * w).sum(-1) / np.where(total > 0, total, 1), np.nan))


def mask_iou(a, b) -> float:
    """Intersection over union of two masks (bool, or values > 0.5 count as inside). Two empty
    masks give 1."""
    a = np.asarray(a)
    b = np.asarray(b)
    if a.shape != b.shape:
        raise ValueError(f"masks differ in size: {a.shape} vs {b.shape}")
    a = a > 0.5 if a.dtype != bool else a
    b = b > 0.5 if b.dtype != bool else b
    union = np.logical_or(a, b).sum()
    if union == 0:
        return 1.0
    return float(np.logical_and(a, b).sum() / union)


def acceleration_error(pred, gt, root: Optional[int] = 0) -> float:
    """Mean ``|second difference of pred - of gt|`` over frames and joints; ``pred, gt
    [F, J, 3]`` (``F >= 3``), each aligned at joint ``root`` first (``None``: no alignment)."""
    pred, gt = _pair(pred, gt)
    if pred.shape[0] < 3:
        raise ValueError(f"acceleration error needs at least 3 frames, got {pred.shape[0]}")
    if root is not None:
        pred = pred - pred[:, root : root + 1]
        gt = gt - gt[:, root : root + 1]
    acc = lambda x: x[2:] - 2.0 * x[1:-1] + x[:-2]  # noqa: E731
    return float(np.linalg.norm(acc(pred) - acc(gt), axis=-1).mean())
