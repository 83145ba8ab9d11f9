"""The run store: what counts as done, and the repairs made on start."""

import json

from silfit.runner.store import FAILURES, RESULTS, RunStore, read_jsonl


def _ok(key):
    return {"item": key, "status": "ok"}


def _failed(key):
    return {"item": key, "status": "failed", "error": {"file": "f", "field": "x", "message": "bad"}}


def test_open_repairs_a_killed_run(tmp_path):
    out = tmp_path / "out"
    store = RunStore.open(out, ["a", "b", "c", "d"])
    for key in ("a", "b"):
        (out / key).mkdir()
        (out / key / "params.npz").write_bytes(b"x")
    store.add([_ok("a"), _ok("b"), _failed("c")])
    # a kill: half a line, a temporary folder of an interrupted write, a folder moved into
    # place but not recorded, a recorded folder that was since deleted
    with open(out / RESULTS, "a") as fh:
        fh.write('{"item": "d", "sta')
    (out / ".d.x1y2z3").mkdir()
    (out / "d").mkdir()
    (out / "d" / "params.npz").write_bytes(b"x")
    import shutil

    shutil.rmtree(out / "b")
    store = RunStore.open(out, ["a", "b", "c", "d"])
    assert sorted(store.records) == ["a", "c"]
    assert not (out / ".d.x1y2z3").exists()
    assert [r["item"] for r in read_jsonl(out / RESULTS)] == ["a", "c"]
    assert (out / RESULTS).read_text().endswith("\n")
    assert [f["item"] for f in read_jsonl(out / FAILURES)] == ["c"]
    # retrying failures drops their lines, so the item ends with one line
    store = RunStore.open(out, ["a", "b", "c", "d"], retry_failed=True)
    assert sorted(store.records) == ["a"] and read_jsonl(out / FAILURES) == []
    store.add([_ok("c")])
    lines = [json.loads(x) for x in (out / RESULTS).read_text().splitlines()]
    assert [r["item"] for r in lines] == ["a", "c"]
