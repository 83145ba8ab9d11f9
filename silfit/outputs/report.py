"""``silfit report DIR``: a static HTML gallery of many fits (``DIR/report/index.html``).

DIR is a ``silfit fit-dataset`` output (``results.jsonl`` and one folder per item), a folder of
``silfit fit`` output folders, or one fit's folder. The report is one ``index.html`` (inline CSS and
JavaScript, nothing fetched: it opens from disk in any browser, no server) and ``side/<n>.png``:
one card per fit with its ``overlay.png`` (a relative link to the fit's own file), a side view
(the fitted body turned 90 degrees about the camera's vertical axis: depth errors show there), the
median reprojection error, the IoU (keypoint stage -> final, with a mask), the warnings, and for a
failed item the failing file, field and message. The cards sort by any metric in the page,
worst first by default (failed items first, then lowest IoU where any fit has one, else highest
reprojection error); ``#sort=<key>&order=<worst|best>`` in the address picks the order too.
"""

from __future__ import annotations

import html
import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import List, Optional, Union
from urllib.parse import quote

import numpy as np
import trimesh

from ..camera import Camera
from ..io.limits import read_json
from ..io.subjects import write_png
from ..runner.store import read_jsonl
from .figures import paint_mesh

__all__ = ["Card", "collect_cards", "side_view", "write_report", "SORT_KEYS"]

#: Sort keys of the page: key -> (label, the order that puts the worst first).
SORT_KEYS = {
    "iou": ("IoU (final)", "asc"),
    "reproj": ("reprojection error (px)", "desc"),
    "iou_kp": ("IoU after the keypoint stage", "asc"),
    "warnings": ("warnings", "desc"),
    "item": ("item name", "asc"),
}
#: Largest mesh.obj drawn as a side view (bytes); larger ones get no side view.
MAX_MESH_BYTES = 256 * 1024**2


@dataclass
class Card:
    """One fit (or failed item) of the report."""

    item: str
    folder: Optional[Path]
    status: str = "ok"
    reprojection_error_px: Optional[float] = None
    iou: Optional[float] = None
    iou_keypoint_stage: Optional[float] = None
    warnings: List[str] = field(default_factory=list)
    error: str = ""
    stages: str = ""


def _number(value) -> Optional[float]:
    try:
        v = float(value)
    except (TypeError, ValueError):
        return None
    return v if np.isfinite(v) else None


def _card(item: str, folder: Optional[Path], record: dict) -> Card:
    warnings = record.get("warnings", [])
    stages = record.get("stages", [])
    return Card(
        item=item,
        folder=folder,
        status=str(record.get("status", "ok")),
        reprojection_error_px=_number(record.get("reprojection_error_px")),
        iou=_number(record.get("iou")),
        iou_keypoint_stage=_number(record.get("iou_keypoint_stage")),
        warnings=[str(w) for w in warnings] if isinstance(warnings, list) else [str(warnings)],
        stages=" + ".join(str(s) for s in stages) if isinstance(stages, list) else str(stages),
    )


def _metrics(folder: Path) -> dict:
    try:
        metrics = read_json(folder / "metrics.json", "metrics")
    except (OSError, ValueError) as err:
        return {"status": "unreadable", "error": str(err)}
    return metrics if isinstance(metrics, dict) else {"status": "unreadable", "error": "metrics.json is not an object"}


def collect_cards(folder: Union[str, os.PathLike]) -> List[Card]:
    """The fits under ``folder`` (see the module docstring), in the order found."""
    folder = Path(folder)
    if not folder.is_dir():
        raise FileNotFoundError(f"{folder}: not a folder")
    cards = []
    records = read_jsonl(folder / "results.jsonl")
    if records:  # a fit-dataset output: its records, the failed ones too
        for r in records:
            if not isinstance(r, dict) or not isinstance(r.get("item"), str):
                continue
            item = r["item"]
            sub = folder / item
            if r.get("status") == "failed":
                e = r.get("error") if isinstance(r.get("error"), dict) else {}
                where = ": ".join(str(e[k]) for k in ("file", "field") if e.get(k))
                cards.append(
                    Card(
                        item,
                        None,
                        "failed",
                        error=f"{r.get('stage', '?')} stage: {where}: {e.get('message', '')}".strip(),
                    )
                )
            elif sub.is_dir():
                cards.append(_card(item, sub, {**_metrics(sub), **r}))
        return cards
    fits = (
        [folder]
        if (folder / "metrics.json").is_file()
        else sorted(p for p in folder.iterdir() if p.is_dir() and (p / "metrics.json").is_file())
    )
    for sub in fits:
        m = _metrics(sub)
        card = _card(sub.name, sub, m)
        if m.get("status") == "unreadable":
            card.status, card.error = "failed", str(m.get("error", ""))
        cards.append(card)
    if not cards:
        raise FileNotFoundError(f"{folder}: no fits here (no results.jsonl, no folders with metrics.json)")
    return cards


# ---------------------------------------------------------------------------------------------- side view
def side_view(vertices: np.ndarray, faces: np.ndarray, size=(120, 180)) -> np.ndarray:
    """``[H, W, 3]`` uint8: the camera-frame body turned 90 degrees about the camera's vertical (y)
    axis through its centre, seen from far away (near orthographic), on a light grey canvas."""
    v = np.asarray(vertices, dtype=np.float64)
    centre = (v.max(0) + v.min(0)) / 2
    turn = np.array([[0.0, 0.0, -1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]])  # the body's right side to the viewer
    p = (v - centre) @ turn.T
    w, h = size
    metres_per_px = max(np.ptp(p[:, 0]) / w, np.ptp(p[:, 1]) / h, 1e-6) * 1.1
    distance = 20.0
    cam = Camera(fx=distance / metres_per_px, fy=distance / metres_per_px, cx=w / 2, cy=h / 2, width=w, height=h)
    rgba = paint_mesh(p + [0.0, 0.0, distance], faces, cam)
    a = rgba[..., 3:].astype(np.float32) / 255.0
    out = np.full((h, w, 3), 235.0) * (1 - a) + rgba[..., :3] * a
    return np.clip(out + 0.5, 0, 255).astype(np.uint8)


def _mesh(folder: Path):
    """``(vertices, faces)`` of a fit's ``mesh.obj`` (camera frame), or ``None``."""
    path = folder / "mesh.obj"
    if not path.is_file() or path.stat().st_size > MAX_MESH_BYTES:
        return None
    try:
        mesh = trimesh.load(path, process=False, force="mesh")
    except Exception:  # noqa: BLE001 - a broken mesh loses its side view, not the report
        return None
    if not len(mesh.faces):
        return None
    return np.asarray(mesh.vertices), np.asarray(mesh.faces)


# ---------------------------------------------------------------------------------------------- page
def _fmt(v: Optional[float], digits: int) -> str:
    return "&ndash;" if v is None else f"{v:.{digits}f}"


def _data(v: Optional[float]) -> str:
    return "" if v is None else repr(float(v))


def _link(path: Path, base: Path) -> str:
    return quote(Path(os.path.relpath(path, base)).as_posix())


def _card_html(n: int, card: Card, report: Path, side: Optional[str]) -> str:
    e = html.escape
    attrs = (
        f'data-item="{e(card.item)}" data-failed="{1 if card.status != "ok" else 0}" '
        f'data-reproj="{_data(card.reprojection_error_px)}" data-iou="{_data(card.iou)}" '
        f'data-iou_kp="{_data(card.iou_keypoint_stage)}" data-warnings="{len(card.warnings)}"'
    )
    pics = []
    if card.folder is not None:
        for name in ("overlay.png", "strip.png"):
            if (card.folder / name).is_file():
                pics.append(
                    f'<a href="{_link(card.folder / name, report)}"><img src="{_link(card.folder / name, report)}" '
                    f'alt="overlay of {e(card.item)}" loading="lazy" class="overlay"></a>'
                )
                break
    if side:
        pics.append(f'<img src="{side}" alt="side view of {e(card.item)}" loading="lazy" class="side">')
    rows = [f"<tr><th>reprojection error</th><td>{_fmt(card.reprojection_error_px, 2)} px</td></tr>"]
    if card.iou is not None or card.iou_keypoint_stage is not None:
        rows.append(f"<tr><th>IoU</th><td>{_fmt(card.iou_keypoint_stage, 3)} &rarr; {_fmt(card.iou, 3)}</td></tr>")
    if card.stages:
        rows.append(f"<tr><th>stages</th><td>{e(card.stages)}</td></tr>")
    body = (
        f"<table>{''.join(rows)}</table>"
        if card.status == "ok"
        else f'<p class="error">{e(card.error or card.status)}</p>'
    )
    warn = "".join(f"<li>{e(w)}</li>" for w in card.warnings)
    title = e(card.item)
    if card.folder is not None:
        title = f'<a href="{_link(card.folder, report)}/">{title}</a>'
    return (
        f'<div class="card{" failed" if card.status != "ok" else ""}" id="card-{n}" {attrs}>'
        f'<h2>{title}</h2><div class="pics">{"".join(pics)}</div>{body}'
        f"{f'<ul class=warnings>{warn}</ul>' if warn else ''}</div>"
    )


_CSS = """
body{font-family:system-ui,sans-serif;margin:1em;background:#fafafa;color:#222}
header{display:flex;flex-wrap:wrap;gap:1em;align-items:baseline}
h1{font-size:1.3em;margin:0}
#grid{display:flex;flex-wrap:wrap;gap:10px;margin-top:1em}
.card{background:#fff;border:1px solid #ccc;border-radius:6px;padding:6px;width:330px;font-size:13px}
.card.failed{border-color:#c33;background:#fff4f4}
.card h2{font-size:13px;margin:0 0 4px;overflow-wrap:anywhere}
.pics{display:flex;gap:4px;align-items:flex-start}
.pics img.overlay{max-width:200px;max-height:200px}
.pics img.side{max-width:120px;max-height:200px}
table{border-collapse:collapse}th{text-align:left;font-weight:normal;color:#666;padding-right:8px}
.warnings{color:#a60;margin:4px 0 0;padding-left:18px}.error{color:#c33;overflow-wrap:anywhere}
"""

_JS = """
(function(){
  var KEYS = %s;
  var grid = document.getElementById('grid');
  var keySel = document.getElementById('sort-key'), orderSel = document.getElementById('sort-order');
  function value(card, key){
    if (key === 'item') return card.dataset.item;
    var v = card.dataset[key];
    return v === '' || v === undefined ? null : parseFloat(v);
  }
  function sortCards(key, order){
    var worstAsc = KEYS[key][1] === 'asc';
    var asc = order === 'worst' ? worstAsc : !worstAsc;
    var cards = Array.prototype.slice.call(grid.children);
    cards.sort(function(a, b){
      var fa = +a.dataset.failed, fb = +b.dataset.failed;
      if (fa !== fb) return order === 'worst' ? fb - fa : fa - fb;
      var va = value(a, key), vb = value(b, key);
      if (va === null || vb === null) return (va === null) - (vb === null);
      var c = va < vb ? -1 : va > vb ? 1 : 0;
      if (c === 0) c = a.dataset.item < b.dataset.item ? -1 : a.dataset.item > b.dataset.item ? 1 : 0;
      return asc ? c : -c;
    });
    cards.forEach(function(c){ grid.appendChild(c); });
    document.body.setAttribute('data-sorted', key + ':' + order);
  }
  function apply(){ sortCards(keySel.value, orderSel.value); }
  var hash = {};
  location.hash.replace(/^#/, '').split('&').forEach(function(kv){
    var p = kv.split('='); if (p.length === 2) hash[decodeURIComponent(p[0])] = decodeURIComponent(p[1]);
  });
  if (KEYS[hash.sort]) keySel.value = hash.sort;
  if (hash.order === 'best' || hash.order === 'worst') orderSel.value = hash.order;
  keySel.addEventListener('change', apply); orderSel.addEventListener('change', apply);
  apply();
})();
"""


def _summary(cards: List[Card]) -> str:
    ok = [c for c in cards if c.status == "ok"]
    parts = [f"{len(cards)} items", f"{len(ok)} fitted", f"{len(cards) - len(ok)} failed"]
    for label, values, digits in (
        ("median reprojection error", [c.reprojection_error_px for c in ok], 2),
        ("median IoU", [c.iou for c in ok], 3),
    ):
        values = [v for v in values if v is not None]
        if values:
            parts.append(f"{label} {float(np.median(values)):.{digits}f}")
    parts.append(f"{sum(len(c.warnings) for c in ok)} warnings")
    return ", ".join(parts)


def write_report(
    folder: Union[str, os.PathLike], out: Union[str, os.PathLike, None] = None, side_views: bool = True
) -> Path:
    """Write the gallery of the fits under ``folder`` into ``out`` (default ``folder/report``);
    returns its ``index.html``."""
    folder = Path(folder)
    cards = collect_cards(folder)
    report = Path(out) if out is not None else folder / "report"
    if (report / "metrics.json").is_file() or (report / "params.npz").is_file():
        raise ValueError(f"{report}: this folder holds a fit; choose another report folder (--out)")
    (report / "side").mkdir(parents=True, exist_ok=True)
    for old in (report / "side").glob("[0-9][0-9][0-9][0-9][0-9].png"):  # a previous report's side views
        old.unlink()
    html_cards = []
    for n, card in enumerate(cards):
        side = None
        mesh = _mesh(card.folder) if side_views and card.folder is not None and card.status == "ok" else None
        if mesh is not None:
            write_png(report / "side" / f"{n:05d}.png", side_view(*mesh))
            side = f"side/{n:05d}.png"
        html_cards.append(_card_html(n, card, report, side))
    has_iou = any(c.iou is not None for c in cards)
    default = "iou" if has_iou else "reproj"
    options = "".join(
        f'<option value="{k}"{" selected" if k == default else ""}>{html.escape(label)}</option>'
        for k, (label, _) in SORT_KEYS.items()
    )
    keys_js = json.dumps(SORT_KEYS)
    page = f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>silfit report: {html.escape(folder.name)}</title>
<meta name="viewport" content="width=device-width, initial-scale=1"><style>{_CSS}</style></head>
<body data-sorted="">
<header><h1>silfit report: {html.escape(folder.name)}</h1><span id="summary">{html.escape(_summary(cards))}</span>
<label>sort by <select id="sort-key">{options}</select></label>
<label><select id="sort-order"><option value="worst" selected>worst first</option><option value="best">best first</option></select></label>
</header>
<div id="grid">{"".join(html_cards)}</div>
<script>{_JS % keys_js}</script>
</body></html>
"""
    index = report / "index.html"
    tmp = index.with_name(".index.html.tmp")
    tmp.write_text(page, encoding="utf-8")
    os.replace(tmp, index)
    return index
