"""``silfit report`` / the report at the end of ``fit-dataset``: the gallery renders in a real headless
Chromium (Debian's ``chromium``, installed by tools/setup.sh), whose JavaScript sorts the cards."""

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from runner.helpers import FAST, synthetic_copy  # noqa: E402

from silfit.cli import main  # noqa: E402
from silfit.outputs.report import side_view  # noqa: E402


def chromium(*args, timeout=120):
    exe = shutil.which("chromium") or shutil.which("chromium-browser")
    if exe is None:
        pytest.fail("Debian's chromium is not installed (tools/setup.sh installs it): the report is tested in it")
    cmd = [exe, "--headless", "--no-sandbox", "--disable-gpu", "--allow-file-access-from-files", *map(str, args)]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, check=True).stdout


def card_order(dom: str) -> list:
    return re.findall(r'<div class="card[^"]*" id="card-\d+" data-item="([^"]*)"', dom)


@pytest.fixture(scope="module")
def dataset_run(tmp_path_factory):
    """A real fit-dataset run over four items (one fails to load); its report is written at the end."""
    tmp = tmp_path_factory.mktemp("report")
    data = synthetic_copy(tmp / "data", [f"subject_{i:03d}" for i in range(4)])
    (data / "subject_001" / "keypoints.json").write_text("{broken")
    out = tmp / "out"
    assert main(["fit-dataset", str(data), "--out", str(out), "--no-silhouette", "--quiet", *FAST]) == 11
    return out


def test_fit_dataset_writes_a_report_that_chromium_sorts_worst_first(dataset_run):
    index = dataset_run / "report" / "index.html"
    assert index.is_file()
    page = index.read_text()
    assert "http://" not in page and "https://" not in page  # nothing fetched
    records = {r["item"]: r for r in map(json.loads, (dataset_run / "results.jsonl").read_text().splitlines())}
    ok = [k for k, r in records.items() if r["status"] == "ok"]
    worst_first = ["subject_001"] + sorted(ok, key=lambda k: -records[k]["reprojection_error_px"])
    assert card_order(page)[:2] == ["subject_000", "subject_001"]  # the file holds the records' order ...
    dom = chromium("--dump-dom", index.as_uri())
    assert 'data-sorted="reproj:worst"' in dom  # the page's script ran
    assert card_order(dom) == worst_first  # ... the page's script sorts them
    best = chromium("--dump-dom", index.as_uri() + "#sort=reproj&order=best")
    assert card_order(best) == sorted(ok, key=lambda k: records[k]["reprojection_error_px"]) + ["subject_001"]
    # overlays are the fits' own files, by relative path; side views are in the report
    for k in ok:
        assert f'src="../{k}/overlay.png"' in page
    assert len(list((dataset_run / "report" / "side").glob("*.png"))) == len(ok)
    assert "keypoints.json" in page and "not valid JSON" in page  # the failed item's card says why


def test_report_screenshot_shows_the_cards(dataset_run, tmp_path):
    shot = tmp_path / "shot.png"
    chromium(f"--screenshot={shot}", "--window-size=1000,700", (dataset_run / "report" / "index.html").as_uri())
    img = np.asarray(Image.open(shot).convert("RGB"))
    assert img.shape == (700, 1000, 3)
    failed_border = (np.abs(img.astype(int) - [0xCC, 0x33, 0x33]).sum(-1) < 30).sum()
    body_grey = (np.abs(img.astype(int) - [235, 235, 235]).sum(-1) < 4).sum()  # the side views' canvas
    assert failed_border > 200 and body_grey > 5000  # the failed card's red frame and the side views are drawn


def test_report_out_and_no_side_views(dataset_run, tmp_path):
    assert main(["report", str(dataset_run), "--out", str(tmp_path / "plain"), "--no-side-views"]) == 0
    page = (tmp_path / "plain" / "index.html").read_text()
    assert 'class="side"' not in page and not list((tmp_path / "plain" / "side").glob("*.png"))
    assert f'src="{os.path.relpath(dataset_run / "subject_000" / "overlay.png", tmp_path / "plain")}"' in page
    assert 'class="side"' in (dataset_run / "report" / "index.html").read_text()


def _fake_fit(folder: Path, name: str, metrics: dict) -> None:
    (folder / name).mkdir(parents=True)
    (folder / name / "metrics.json").write_text(json.dumps(metrics))


def test_report_of_fit_folders_sorts_by_any_metric_and_escapes_text(tmp_path, capsys):
    _fake_fit(tmp_path, "b", {"reprojection_error_px": 3.0, "iou_keypoint_stage": 0.7, "iou": 0.9, "warnings": []})
    _fake_fit(
        tmp_path,
        "a",
        {
            "reprojection_error_px": 1.0,
            "iou_keypoint_stage": 0.6,
            "iou": 0.5,
            "warnings": ["<script>alert(1)</script>", "two"],
        },
    )
    _fake_fit(tmp_path, "c", {"reprojection_error_px": 2.0, "iou_keypoint_stage": 0.8, "iou": 0.7, "warnings": ["one"]})
    (tmp_path / "d").mkdir()
    (tmp_path / "d" / "metrics.json").write_text("{not json")
    assert main(["report", str(tmp_path), "--out", str(tmp_path / "r")]) == 0
    index = tmp_path / "r" / "index.html"
    assert str(index) in capsys.readouterr().out
    page = index.read_text()
    assert "<script>alert" not in page and "&lt;script&gt;alert(1)&lt;/script&gt;" in page
    assert card_order(chromium("--dump-dom", index.as_uri())) == ["d", "a", "c", "b"]  # default: lowest IoU first
    for sort, order, expected in (
        ("reproj", "worst", ["d", "b", "c", "a"]),
        ("iou_kp", "worst", ["d", "a", "b", "c"]),
        ("warnings", "worst", ["d", "a", "c", "b"]),
        ("item", "worst", ["d", "a", "b", "c"]),
        ("iou", "best", ["b", "c", "a", "d"]),
    ):
        dom = chromium("--dump-dom", index.as_uri() + f"#sort={sort}&order={order}")
        assert f'data-sorted="{sort}:{order}"' in dom and card_order(dom) == expected, sort


def test_report_of_nothing_is_an_error(tmp_path, capsys):
    assert main(["report", str(tmp_path)]) == 2
    assert "no fits here" in capsys.readouterr().err and not (tmp_path / "report").exists()


def test_side_view_turns_the_body(open_model):
    import torch

    with torch.no_grad():
        v = open_model(
            global_orient=torch.tensor([[np.pi, 0.0, 0.0]]), transl=torch.tensor([[0.0, 0.0, 3.0]])
        ).vertices[0]
    img = side_view(v.numpy(), open_model.faces.numpy(), size=(120, 180))
    body = np.abs(img.astype(int) - 235).sum(-1) > 10
    cols = np.flatnonzero(body.any(0))
    rows = np.flatnonzero(body.any(1))
    assert np.ptp(rows) > 150 and np.ptp(cols) < 0.3 * np.ptp(
        rows
    )  # from the side: tall and narrow (the T-pose arms point at the viewer)
