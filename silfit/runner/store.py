"""The output folder of a dataset run and what makes it resumable.

``OUT/<item>/`` holds one fit in ``silfit fit``'s layout (:func:`silfit.run.write` writes it
into a temporary ``OUT/.<item>.*`` folder and renames it into place). ``OUT/results.jsonl``
has one line per item (``status`` ``ok`` or ``failed``), ``OUT/failures.jsonl`` one line per
failed item (``item, file, field, message``). Only this process (the driver) writes the
two files, a line at a time, flushed and synced.

An item is complete when its ``ok`` line is in ``results.jsonl`` *and* its folder is in place.
On start (:meth:`RunStore.open`): a line cut off by a kill is dropped; temporary folders of
interrupted writes are removed; the lines of items that will run again (folder missing,
or failed with ``retry_failed``) are removed, so every item ends with exactly one line.
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path
from typing import Dict, Iterable, List, Optional

__all__ = ["RESULTS", "FAILURES", "RunStore", "read_jsonl"]

RESULTS = "results.jsonl"
FAILURES = "failures.jsonl"


def read_jsonl(path: Path) -> List[dict]:
    """The complete lines of a JSON Lines file (a last line without its newline, as a kill
    leaves it, is not complete and is skipped)."""
    if not path.is_file():
        return []
    text = path.read_text(encoding="utf-8")
    lines = text.split("\n")
    out = []
    for line in lines[:-1]:  # the part after the last newline is incomplete
        if line.strip():
            try:
                out.append(json.loads(line))
            except json.JSONDecodeError:
                continue
    return out


def _rewrite(path: Path, rows: Iterable[dict]) -> None:
    tmp = path.with_name(f".{path.name}.tmp")
    with open(tmp, "w", encoding="utf-8") as fh:
        for row in rows:
            fh.write(json.dumps(row) + "\n")
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, path)


def is_temporary(name: str) -> bool:
    """A folder name :func:`silfit.run.write` uses while writing (``.<item>.<random>``)."""
    return name.startswith(".") and name.count(".") >= 2 and not name.endswith(".tmp")


class RunStore:
    def __init__(self, out: Path, records: Dict[str, dict], failures: Dict[str, dict]):
        self.out, self.records, self.failures = out, records, failures

    @classmethod
    def open(cls, out, keys: Iterable[str], retry_failed: bool = False) -> "RunStore":
        """Prepare ``out`` for a run over ``keys`` (see the module docstring)."""
        out = Path(out)
        out.mkdir(parents=True, exist_ok=True)
        for p in out.iterdir():
            if p.is_dir() and is_temporary(p.name):
                shutil.rmtree(p, ignore_errors=True)
        keys = set(keys)
        records: Dict[str, dict] = {}
        for r in read_jsonl(out / RESULTS):
            if isinstance(r, dict) and isinstance(r.get("item"), str):
                records[r["item"]] = r  # the last line of an item wins
        keep = {}
        for key, r in records.items():
            if r.get("status") == "ok" and (out / key / "params.npz").is_file():
                keep[key] = r
            elif r.get("status") == "failed" and not (retry_failed and key in keys):
                keep[key] = r
        failures = {
            f["item"]: f
            for f in read_jsonl(out / FAILURES)
            if isinstance(f, dict) and keep.get(f.get("item"), {}).get("status") == "failed"
        }
        _rewrite(out / RESULTS, keep.values())
        _rewrite(out / FAILURES, failures.values())
        return cls(out, keep, failures)

    def done(self, key: str) -> bool:
        return key in self.records

    def add(self, records: List[dict]) -> None:
        """Record finished items (their folders are already in place)."""
        with (
            open(self.out / RESULTS, "a", encoding="utf-8") as res,
            open(self.out / FAILURES, "a", encoding="utf-8") as fail,
        ):
            for r in records:
                if r["status"] == "failed":
                    f = {"item": r["item"], **r["error"]}
                    fail.write(json.dumps(f) + "\n")
                    self.failures[r["item"]] = f
            fail.flush()
            os.fsync(fail.fileno())
            for r in records:
                res.write(json.dumps(r) + "\n")
                self.records[r["item"]] = r
            res.flush()
            os.fsync(res.fileno())

    def for_keys(self, keys: Iterable[str]) -> List[dict]:
        return [self.records[k] for k in keys if k in self.records]

    def folder(self, key: str) -> Path:
        return self.out / key

    def get(self, key: str) -> Optional[dict]:
        return self.records.get(key)
