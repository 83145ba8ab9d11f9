"""Functional core of the SMPL body model: pure, batched, differentiable torch functions.

Shapes use ``B`` for the batch, ``V`` vertices, ``J`` joints and ``L`` shape
directions. Every function works in float32 and float64 and on any device.

**Batch invariance.** A matrix product over a batch is one GEMM whose blocking, and so whose
rounding, depends on how many rows it holds: a body computed alone and the same body in a batch
of 8 differed in the last bits, which a fit's optimiser amplifies into a different fit. The
large contractions (:func:`pose_correctives`, :func:`vertices_to_joints`, the blending of
:func:`skin_vertices`) therefore go through
:func:`per_row`: each batch row is its own product; the short ones (:func:`blend_shapes`) are a
broadcast product and a sum. Either way a row's values (and gradients) do not depend on the other
rows, their number or its position (``tests/body/test_lbs.py``). The small per-joint products
(3x3, 4x4) are per-row already.

**No BLAS.** A GEMM's result also follows the BLAS library's choice of kernel, which changes with
the processor (MKL on an Intel CPU with AVX-512 against an AMD one, even with ``MKL_CBWR=AVX2``) and
with its thread count: on an Intel Xeon the same float64 keypoint fit differed between one and two MKL
threads and from an AMD machine's (docs/benchmarks/defaults.md). So the products here are torch's own
elementwise kernels (a broadcast product and a sum, :func:`matmul` for the small matrices, the
joint regressor over its nonzeros, :func:`sparse_contract`), whose order of operations silfit pins
(:mod:`silfit.kernels`) and which split these sums across threads by output, never inside one
(a sum down to a single value of more than 32,768 numbers does split by thread). Two
GEMMs remain, neither in the keypoint stage's default energy: an official model's pose correctives and the
skinning of a whole mesh (:func:`skin_vertices`; over the weights' nonzeros it is slower, so that is
asked for only where a result must be the same bits everywhere: ``skin_vertices(..., blas=False)``,
``pose_correctives(..., blas=False)``, as the interpenetration spheres are built).

**No VML square root.** torch hands ``torch.sqrt`` (and ``pow(x, 0.5)``) of a float tensor to MKL's
vector maths, whose result is not the correctly rounded one (on an AMD EPYC some float64 and float32
values are 1 ulp off: docs/benchmarks/defaults.md) and follows the processor: an Intel Xeon with AVX-512
rounds other values.
:func:`sqrt` is computed from ``rsqrt`` (the processor's own square root and a division, both correctly
rounded by IEEE 754) and one product: the same bits on every processor. The fitting path uses it.
"""

from __future__ import annotations

import weakref
from typing import Optional, Sequence

import torch

__all__ = [
    "skew",
    "sqrt",
    "axis_angle_to_matrix",
    "per_row",
    "matmul",
    "sparse_contract",
    "blend_shapes",
    "pose_feature",
    "pose_correctives",
    "vertices_to_joints",
    "kinematic_levels",
    "forward_kinematics",
    "skin_vertices",
    "lbs",
]


class _Sqrt(torch.autograd.Function):
    """``x * rsqrt(x)`` (0 at 0, infinity at infinity); the gradient ``grad * rsqrt(x) / 2`` (module docstring, "No VML
    square root")."""

    @staticmethod
    def forward(ctx, x):
        r = torch.rsqrt(x)
        ctx.save_for_backward(r)
        return torch.where((x == 0) | torch.isinf(x), x, x * r)

    @staticmethod
    def backward(ctx, grad):
        (r,) = ctx.saved_tensors
        return grad * (0.5 * r)


def sqrt(x: torch.Tensor) -> torch.Tensor:
    """The square root of ``x``, differentiable, within 2 ulp of the exact one and the same bits on every
    processor (``torch.sqrt`` is not: module docstring, "No VML square root"). Negative values give NaN."""
    return _Sqrt.apply(x)


def skew(v: torch.Tensor) -> torch.Tensor:
    """Cross-product matrices ``[..., 3, 3]`` of vectors ``[..., 3]``."""
    x, y, z = v.unbind(-1)
    o = torch.zeros_like(x)
    return torch.stack([o, -z, y, z, o, -x, -y, x, o], dim=-1).reshape(v.shape[:-1] + (3, 3))


def axis_angle_to_matrix(axis_angle: torch.Tensor) -> torch.Tensor:
    """Rodrigues' formula, ``[..., 3]`` -> ``[..., 3, 3]``.

    Written as ``R = I + a(t) K + b(t) K^2`` with ``K`` the cross-product matrix of the
    (unnormalised) axis-angle vector, ``a = sin(t)/t`` and ``b = (1 - cos t)/t^2``; both
    are replaced by their Taylor series near ``t = 0`` so values *and* gradients are
    exact and finite at the zero rotation (where SMPL's rest pose lives).
    """
    theta2 = (axis_angle * axis_angle).sum(-1)
    small = theta2 < 1e-6
    safe2 = torch.where(small, torch.ones_like(theta2), theta2)
    theta = sqrt(safe2)
    a = torch.where(small, 1.0 - theta2 / 6.0 + theta2 * theta2 / 120.0, torch.sin(theta) / theta)
    b = torch.where(small, 0.5 - theta2 / 24.0 + theta2 * theta2 / 720.0, (1.0 - torch.cos(theta)) / safe2)
    K = skew(axis_angle)
    eye = torch.eye(3, dtype=axis_angle.dtype, device=axis_angle.device)
    return eye + a[..., None, None] * K + b[..., None, None] * matmul(K, K)


class _OwnGradient(torch.autograd.Function):
    """The identity, whose gradient is handed on as a fresh copy: a slice of a batch's gradient
    starts wherever its row does, and a BLAS may take another path (another rounding) for data
    that is not aligned as a fresh allocation is."""

    @staticmethod
    def forward(ctx, x):
        return x.clone()

    @staticmethod
    def backward(ctx, grad):
        return grad.clone(memory_format=torch.contiguous_format)


def matmul(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """``a @ b`` for small matrices ``[..., n, k] @ [..., k, m]`` (broadcast leading axes) as a
    broadcast product and a sum over ``k``: torch's own kernels, not BLAS (module docstring), so the
    same bits on every processor with silfit's pinned kernels and for any thread count."""
    return (a[..., :, :, None] * b[..., None, :, :]).sum(-2)


def per_row(fn, x: torch.Tensor, *args) -> torch.Tensor:
    """``fn(x, *args)`` computed for each row of ``x``'s leading (batch) axis on its own and
    concatenated: the same bits for a row whatever else is in the batch (module docstring).
    ``fn`` maps ``[1, ...]`` to ``[1, ...]``."""
    if x.shape[0] == 1:
        return fn(x, *args)
    # each row, and its gradient, in its own allocation (_OwnGradient): a slice's start depends on
    # the row's position and on the batch
    own = _OwnGradient.apply
    return torch.cat([own(fn(own(x[i : i + 1]), *args)) for i in range(x.shape[0])])


def blend_shapes(betas: torch.Tensor, shapedirs: torch.Tensor) -> torch.Tensor:
    """Shape offsets ``[B, V, 3]`` from ``betas [B, L]`` and ``shapedirs [V, 3, L]`` (any leading
    axes: ``[..., L]`` gives ``[B, ...]``; only the first ``L`` directions are used)."""
    # a product and a sum over the shape axis, not a GEMM: batch-invariant (module docstring) and,
    # with L of 10-20, faster than one product per row
    dirs = shapedirs[..., : betas.shape[-1]]
    return (betas.reshape(betas.shape[0], *([1] * (dirs.ndim - 1)), -1) * dirs).sum(-1)


def pose_feature(rot_mats: torch.Tensor) -> torch.Tensor:
    """SMPL's pose-corrective feature: ``(R_j - I)`` of the non-root joints, ``[B, (J-1)*9]``."""
    eye = torch.eye(3, dtype=rot_mats.dtype, device=rot_mats.device)
    return (rot_mats[:, 1:] - eye).flatten(1)


def pose_correctives(rot_mats: torch.Tensor, posedirs: torch.Tensor, blas: bool = True) -> torch.Tensor:
    """Pose-corrective offsets ``[B, V, 3]`` of ``rot_mats [B, J, 3, 3]`` with ``posedirs [(J-1)*9, V*3]``;
    ``blas=False``: a broadcast product and a sum, not a GEMM (module docstring, "No BLAS")."""
    B = rot_mats.shape[0]
    if blas:
        return per_row(lambda f: f @ posedirs, pose_feature(rot_mats)).reshape(B, -1, 3)
    return per_row(lambda f: (f[..., None] * posedirs).sum(-2), pose_feature(rot_mats)).reshape(B, -1, 3)


_SPARSE: dict = {}  # id(matrix) -> (weak reference, version, the matrix's padded rows, its transpose's)


def padded_nonzeros(matrix: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """``(index [R, k], weight [R, k])``: the columns of each row of ``matrix [R, C]`` that hold a
    nonzero, ascending, zero-padded to ``k``, the most any row holds."""
    nz = matrix != 0
    k = max(int(nz.sum(1).max()) if matrix.numel() else 0, 1)
    index = torch.sort((~nz).to(torch.uint8), dim=1, stable=True).indices[:, :k].contiguous()
    return index, matrix.gather(1, index).contiguous()  # the padding gathers zeros


def sparse_rows(matrix: torch.Tensor) -> Optional[tuple]:
    """The padded nonzeros of ``matrix [R, C]`` and of its transpose (``(index, weight)`` each, see
    :func:`sparse_contract`), kept per tensor and its version; ``None`` where the matrix needs a
    gradient (the dense product is used then). SMPL's joint regressor is sparse (the open model: at
    most 300 of 13,348 vertices per joint), so the contraction costs a fraction of the dense one.
    Writes that bypass the version counter (``matrix.data``, numpy memory shared with it) are not
    seen: the model's buffers are never written."""
    if matrix.requires_grad or matrix.dim() != 2:
        return None
    key = id(matrix)
    version = None if matrix.is_inference() else matrix._version  # inference tensors keep no version
    hit = _SPARSE.get(key)
    if hit is not None and hit[0]() is matrix and hit[1] == version:
        return hit[2]
    value = (*padded_nonzeros(matrix), *padded_nonzeros(matrix.detach().T))
    _SPARSE[key] = (weakref.ref(matrix, lambda _, key=key: _SPARSE.pop(key, None)), version, value)
    return value


class _SparseContract(torch.autograd.Function):
    """``out[b, r] = sum_k weight[r, k] x[b, index[r, k]]``; the gradient is the same contraction
    with the transpose's padded rows: gathers and sums both ways, never a scatter-add (whose order
    of accumulation follows a sort) nor a GEMM."""

    @staticmethod
    def forward(ctx, x, index, weight, index_t, weight_t):
        ctx.sparse = (index_t, weight_t, index, weight)
        return _gather_sum(x, index, weight)

    @staticmethod
    def backward(ctx, grad):
        return _SparseContract.apply(grad, *ctx.sparse), None, None, None, None


def _gather_sum(x: torch.Tensor, index: torch.Tensor, weight: torch.Tensor) -> torch.Tensor:
    w = weight.to(x.dtype).reshape(weight.shape + (1,) * (x.dim() - 2))
    return (x[:, index] * w).sum(2)


def sparse_contract(matrix: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
    """``einsum("rc,bc...->br...", matrix, x)`` over the matrix's nonzeros (:func:`sparse_rows`): per
    output a product and a sum in a fixed order, the same bits on every processor, thread count and
    batch (module docstring); the dense einsum (a GEMM per row) where the matrix needs a gradient."""
    sparse = sparse_rows(matrix)
    if sparse is None:
        return per_row(lambda v: torch.einsum("rc,bc...->br...", matrix, v), x)
    return _SparseContract.apply(x, *sparse)


def vertices_to_joints(regressor: torch.Tensor, vertices: torch.Tensor) -> torch.Tensor:
    """Joints ``[B, J, 3]`` regressed from ``vertices [B, V, 3]`` with ``regressor [J, V]``: over
    each joint's vertices, a product and a sum (not a GEMM: module docstring)."""
    return sparse_contract(regressor, vertices)


def kinematic_levels(parents: Sequence[int]) -> list[list[int]]:
    """Group joints by depth in the kinematic tree (root first) so forward kinematics
    can process one level at a time; a joint's parent is always in an earlier level."""
    depth: list[int] = []
    for j, p in enumerate(parents):
        if p < 0:
            depth.append(0)
        else:
            if p >= j:
                raise ValueError(f"kinematic tree: joint {j} has parent {p}; parents must precede children")
            depth.append(depth[p] + 1)
    levels: list[list[int]] = [[] for _ in range(max(depth) + 1)]
    for j, d in enumerate(depth):
        levels[d].append(j)
    return levels


def forward_kinematics(
    rot_mats: torch.Tensor, joints: torch.Tensor, parents: Sequence[int], levels: Optional[list[list[int]]] = None
) -> tuple[torch.Tensor, torch.Tensor]:
    """Chain local rotations down the kinematic tree.

    ``rot_mats [B, J, 3, 3]`` are local joint rotations (about each joint's rest
    position), ``joints [B, J, 3]`` rest joint positions. Returns the posed joints
    ``[B, J, 3]`` and the skinning transforms ``[B, J, 4, 4]`` that map a rest-pose
    point rigidly attached to joint ``j`` to its posed position.
    """
    if levels is None:
        levels = kinematic_levels(parents)
    B, J = joints.shape[:2]
    parents_t = torch.as_tensor([max(p, 0) for p in parents], device=joints.device)
    rel = joints - torch.where(
        (torch.as_tensor(parents, device=joints.device) >= 0)[None, :, None],
        joints[:, parents_t],
        torch.zeros_like(joints),
    )
    local = torch.cat([rot_mats, rel[..., None]], dim=-1)  # [B, J, 3, 4]
    bottom = joints.new_tensor([0.0, 0.0, 0.0, 1.0]).expand(B, J, 1, 4)
    local = torch.cat([local, bottom], dim=-2)  # [B, J, 4, 4]

    world = [None] * J
    for level in levels:
        if parents[level[0]] < 0:  # depth 0: the roots
            for j in level:
                world[j] = local[:, j]
            continue
        idx = torch.as_tensor(level, device=joints.device)
        par = torch.stack([world[parents[j]] for j in level], dim=1)  # [B, n, 4, 4]
        chained = matmul(par, local[:, idx])
        for k, j in enumerate(level):
            world[j] = chained[:, k]
    world_t = torch.stack(world, dim=1)  # [B, J, 4, 4]
    posed_joints = world_t[..., :3, 3]
    # Remove the rest joint position so the transform applies to rest-pose points.
    offset = (world_t[..., :3, :3] * joints[..., None, :]).sum(-1)
    skinning = world_t.clone()
    skinning[..., :3, 3] = posed_joints - offset
    return posed_joints, skinning


def skin_vertices(
    vertices: torch.Tensor, transforms: torch.Tensor, weights: torch.Tensor, blas: bool = True
) -> torch.Tensor:
    """Linear blend skinning of rest vertices ``[B, V, 3]`` with per-joint transforms
    ``[B, J, 4, 4]`` and skinning weights ``[V, J]``; ``blas=False``: over the weights' nonzeros
    (:func:`sparse_contract`), the same bits on every processor (module docstring, "No BLAS")."""
    # by default a GEMM per row (the keypoint stage's default energy skins no mesh, and the stages and the keypoint
    # fitter's set-up run one torch thread, so one MKL thread): over the weights' nonzeros (sparse_contract)
    # forward and backward are slower (docs/benchmarks/defaults.md)
    if blas:
        T = per_row(lambda t: torch.einsum("vj,bjrc->bvrc", weights, t), transforms[..., :3, :])  # [B, V, 3, 4]
    else:
        T = sparse_contract(weights, transforms[..., :3, :])
    return (T[..., :3] * vertices[..., None, :]).sum(-1) + T[..., 3]


def lbs(
    betas: torch.Tensor,
    full_pose: torch.Tensor,
    v_template: torch.Tensor,
    shapedirs: torch.Tensor,
    posedirs: Optional[torch.Tensor],
    J_regressor: torch.Tensor,
    parents: Sequence[int],
    weights: torch.Tensor,
    levels: Optional[list[list[int]]] = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """The SMPL function: ``(betas [B, L], full_pose [B, J*3] axis-angle)`` to posed
    vertices ``[B, V, 3]`` and joints ``[B, J, 3]`` (before any global translation).

    ``posedirs [(J-1)*9, V*3]`` may be ``None`` for a model without pose correctives.
    """
    B = betas.shape[0]
    v_shaped = v_template[None] + blend_shapes(betas, shapedirs)
    rest_joints = vertices_to_joints(J_regressor, v_shaped)
    rot_mats = axis_angle_to_matrix(full_pose.reshape(B, -1, 3))
    v_posed = v_shaped
    if posedirs is not None:
        v_posed = v_shaped + pose_correctives(rot_mats, posedirs)
    joints, transforms = forward_kinematics(rot_mats, rest_joints, parents, levels)
    return skin_vertices(v_posed, transforms, weights), joints
