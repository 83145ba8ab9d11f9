"""Torch's intra-op thread count during a fit.

A fit's tensors are small (one body, a few thousand pixels), so torch's thread pool
costs more in synchronisation than it gains, and it competes with Dr.Jit's own pool:
silhouette steps run faster with one torch thread (measured: docs/benchmarks/defaults.md).
"""

from __future__ import annotations

from contextlib import contextmanager
from typing import Iterator, Optional

import torch

__all__ = ["torch_threads"]


@contextmanager
def torch_threads(count: Optional[int]) -> Iterator[None]:
    """Run the block with ``count`` torch threads (``None``: leave the setting alone)."""
    previous = torch.get_num_threads()
    if count:
        torch.set_num_threads(int(count))
    try:
        yield
    finally:
        torch.set_num_threads(previous)
