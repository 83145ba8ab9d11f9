"""``silfit.runner.run``: how pending items are cut into batches that several workers share."""

import pytest

import signal

from silfit.runner.run import _sigint_ignored, available_cpus, quota_cpus, shared_batch_size, shared_batches

CASES = [
    (8, 28, 2),
    (8, 30, 2),
    (8, 24, 2),
    (1, 5, 2),
    (4, 4, 2),
    (8, 3, 2),
    (8, 100, 1),
    (32, 100, 4),
    (8, 1, 2),
    (3, 50, 16),
    (8, 13, 6),
    (8, 5, 4),
    (2, 7, 3),
]


@pytest.mark.parametrize("batch, pending, workers", CASES)
def test_batches_are_shared_evenly_and_never_larger_than_asked(batch, pending, workers):
    parts = shared_batches(list(range(pending)), batch, workers)
    sizes = [len(p) for p in parts]
    assert [i for p in parts for i in p] == list(range(pending))  # every item once, in order
    assert 1 <= min(sizes) and max(sizes) <= batch
    if workers == 1:
        assert sizes[:-1] == [batch] * (len(sizes) - 1)  # one worker: the size asked
        return
    assert max(sizes) - min(sizes) <= 1
    # every worker gets work: a multiple of the workers, or one item per batch where the items are too few for that
    assert len(parts) % workers == 0 or len(parts) == pending
    assert len(parts) >= min(workers, pending)
    assert shared_batch_size(batch, pending, workers) == max(sizes)


def test_twenty_eight_items_in_batches_of_eight_for_two_workers_are_four_of_seven():
    assert [len(p) for p in shared_batches(list(range(28)), 8, 2)] == [7, 7, 7, 7]  # not 8, 8, 8 and 4
    assert [len(p) for p in shared_batches(list(range(13)), 8, 6)] == [3, 2, 2, 2, 2, 2]  # six batches for six


def test_sigint_is_ignored_within_the_block_and_restored_unless_an_interrupt_ends_it():
    """The worker processes start within the block (they inherit Ctrl-C ignored). An error or another's
    KeyboardInterrupt ends it with the handler restored; silfit's interrupt (its handler raised, having set
    SIGINT and SIGTERM aside) leaves it ignored."""

    def handler(signum, frame):
        pass

    before = signal.signal(signal.SIGINT, handler)
    try:
        with _sigint_ignored():
            assert signal.getsignal(signal.SIGINT) is signal.SIG_IGN
        assert signal.getsignal(signal.SIGINT) is handler
        with pytest.raises(ValueError):
            with _sigint_ignored():
                raise ValueError("a batch could not be sent")
        assert signal.getsignal(signal.SIGINT) is handler
        with pytest.raises(KeyboardInterrupt):  # another's KeyboardInterrupt: restored
            with _sigint_ignored():
                raise KeyboardInterrupt
        assert signal.getsignal(signal.SIGINT) is handler
        term = signal.getsignal(signal.SIGTERM)
        try:
            with pytest.raises(KeyboardInterrupt):
                with _sigint_ignored():
                    signal.signal(signal.SIGTERM, signal.SIG_IGN)  # as silfit.cli.interrupts' handler does
                    raise KeyboardInterrupt("SIGTERM")
            assert signal.getsignal(signal.SIGINT) is signal.SIG_IGN
        finally:
            signal.signal(signal.SIGTERM, term)
    finally:
        signal.signal(signal.SIGINT, before)


@pytest.mark.parametrize(
    "line, cpus",
    [
        ("max 100000", None),
        ("150000 100000", 2),
        ("100000 100000", 1),
        ("50000 100000", 1),
        ("400000 100000\n", 4),
        ("", None),
        ("x y", None),
    ],
)
def test_a_cgroup_quota_is_read_as_whole_cpus_rounded_up(line, cpus):
    assert quota_cpus(line) == cpus


def test_available_cpus_is_the_affinity_capped_by_the_quota(tmp_path):
    import os

    affinity = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    assert available_cpus(str(tmp_path / "no such file")) == affinity
    (tmp_path / "cpu.max").write_text("max 100000\n")
    assert available_cpus(str(tmp_path / "cpu.max")) == affinity
    (tmp_path / "cpu.max").write_text("100000 100000\n")
    assert available_cpus(str(tmp_path / "cpu.max")) == 1


def test_workers_auto_runs_one_process_per_available_cpu(tmp_path, monkeypatch):
    """``fit_dataset(workers="auto")`` hands the pool :func:`available_cpus`' count (here 3)."""
    from silfit.runner import FitOptions, fit_dataset
    import silfit.runner as runmod  # fit_dataset calls them by these names

    from .helpers import synthetic_copy

    asked = {}

    def pool(store, pending, options, batch_size, workers, progress=True):
        asked["workers"] = workers
        raise KeyboardInterrupt  # nothing fitted: only the count is checked

    monkeypatch.setattr(runmod, "available_cpus", lambda: 3)
    monkeypatch.setattr(runmod, "run_pool", pool)
    data = synthetic_copy(tmp_path / "data", ["subject_000", "subject_001"])
    with pytest.raises(KeyboardInterrupt):
        fit_dataset(data, tmp_path / "out", options=FitOptions(silhouette=False), workers="auto", progress=False)
    assert asked == {"workers": 3}
