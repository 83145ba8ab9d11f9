"""The builders' shape checks: one entry per frame, one per view (a ``ValueError`` otherwise: a caller's mistake,
not a bad input file)."""

from __future__ import annotations

__all__ = ["one_per_frame", "one_per_view"]


def one_per(count: int, unit: str, lists: dict) -> None:
    """Refuse a list of ``lists`` (``None``: not given) whose length is not ``count`` ``unit``s."""
    for name, values in lists.items():
        if values is not None and len(values) != count:
            raise ValueError(f"{len(values)} {name} for {count} {unit}s: one per {unit}")


def one_per_frame(count: int, **lists) -> None:
    """Refuse a list of ``lists`` (``None``: not given) whose length is not ``count`` frames."""
    one_per(count, "frame", lists)


def one_per_view(count: int, **lists) -> None:
    """Refuse a list of ``lists`` (``None``: not given) whose length is not ``count`` views."""
    one_per(count, "view", lists)
