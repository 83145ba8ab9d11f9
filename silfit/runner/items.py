"""Dataset inputs of ``silfit fit-dataset``: what to fit (:class:`Item`, one per image and
person) from the three input kinds, and reading one item's files (:func:`load_item`).

Input kinds (:func:`list_items` picks by what ``INPUT`` is):

* **OpenPose folder**: ``INPUT/<stem>_keypoints.json`` (OpenPose's output, several people
  per file). Optional ``masks`` folder: ``<stem>_<k>.png`` is person ``k``'s mask, ``<stem>.png``
  the mask of the largest person (the one ``--people largest`` picks). Optional ``images``
  folder: ``<stem>.png`` / ``.jpg`` / ``.jpeg``. Camera: ``camera`` a shared ``camera.json``
  or a folder of ``<stem>.json``; else ``INPUT/camera.json`` when there is one; else the
  default camera of the image's (or mask's) size.
* **Manifest** (``.jsonl`` JSON Lines or ``.csv`` with a header): one row per image with
  ``keypoints`` (required), ``mask``, ``image``, ``camera``, ``person`` (an index or
  ``largest``; empty: ``--people``), ``id`` (output folder name; default the keypoint
  file's stem without ``_keypoints``, or its folder's name for a ``keypoints.json``). Relative paths are relative to the manifest's folder.
* **silfit's synthetic format** (:mod:`silfit.io.subjects`): one subject folder per image,
  ``mask.png`` the mask of the subject's largest person.

``people``: ``"largest"`` (one item per image, named by the stem), ``"all"`` (one item per
detected person, named ``<stem>_<k>``) or an index ``K`` (``<stem>_<K>``). A person whose mask
is not given is fitted to the keypoints only.

Errors in one image's files do not stop the listing: that item carries the error and is
reported as failed. Errors in the input as a whole (no such folder, a malformed manifest)
raise :class:`InputError`.
"""

from __future__ import annotations

import csv
import json
import os
import re
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Dict, List, Optional, Union

import numpy as np

from ..camera import Camera, load_camera
from ..errors import InputError, cut_quotes, quoted  # InputError: the dataset input as a whole is unusable
from ..io.subjects import SUBJECT_FILES, SubjectError, list_subjects, read_image, read_mask
from ..io.keypoints import KeypointSet, read_keypoints
from ..io.limits import MAX_JSON_BYTES, check_file_size

__all__ = ["InputError", "ItemError", "Item", "LoadedItem", "list_items", "load_item", "read_people", "parse_people"]

KEYPOINT_SUFFIX = "_keypoints.json"
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")
MANIFEST_COLUMNS = ("id", "keypoints", "mask", "image", "camera", "person")
#: names an item cannot have (the run's own files in OUT)
RESERVED = ("", "..", "results.jsonl", "failures.jsonl", "summary.md", "summary.json", "summary.png")
#: key of :attr:`Item.masks` for the mask of the largest (or only) person
LARGEST = "largest"


#: Longest message recorded for an item (``failures.jsonl``).
MAX_MESSAGE_CHARS = 300


def short_message(message: str, library: bool = False) -> str:
    """``message`` on one line, at most :data:`MAX_MESSAGE_CHARS` characters. A
    ``library`` message (not silfit's own, whose readers quote what a file holds through
    :func:`silfit.errors.quoted`) has its quoted strings cut too
    (:func:`silfit.errors.cut_quotes`): a manifest may name any file."""
    text = " ".join(str(message).split())
    text = cut_quotes(text) if library else text
    return text if len(text) <= MAX_MESSAGE_CHARS else text[: MAX_MESSAGE_CHARS - 3] + "..."


class ItemError(Exception):
    """One item's failure: the ``file`` and ``field`` at fault and a one-line ``message``
    (at most :data:`MAX_MESSAGE_CHARS` characters: :func:`short_message`)."""

    def __init__(self, file: Optional[str], field: str, message: str):
        self.file, self.field, self.message = file, field, short_message(message)
        super().__init__(f"{file}: field '{field}': {message}" if file else message)

    def to_dict(self) -> dict:
        return {"file": self.file, "field": self.field, "message": self.message}


@dataclass
class Item:
    """One (image, person) to fit. Paths are strings (an item travels to Ray workers as JSON).
    ``person``: an index or ``"largest"``; ``masks``: person index (as a string) or
    ``"largest"`` -> mask file; ``error``: a failure found while listing."""

    key: str
    keypoints: Optional[str]
    person: Union[int, str] = LARGEST
    masks: Dict[str, str] = field(default_factory=dict)
    image: Optional[str] = None
    camera: Optional[str] = None
    error: Optional[dict] = None

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> "Item":
        return cls(**d)


@dataclass
class LoadedItem:
    item: Item
    keypoints: KeypointSet
    person: int  # index of the fitted person in the keypoint file
    people: int  # people in the keypoint file
    camera: Camera
    mask: Optional[np.ndarray] = None
    mask_file: Optional[str] = None
    image: Optional[np.ndarray] = None
    #: what the input checks found (keypoints treated as missing, ...)
    warnings: List[str] = field(default_factory=list)


def parse_people(text: str) -> Union[int, str]:
    """``--people``: ``largest``, ``all`` or a person index."""
    if text in ("largest", "all"):
        return text
    try:
        k = int(text)
    except ValueError:
        raise InputError(f"--people {text!r}: expected largest, all or a person index") from None
    if k < 0:
        raise InputError(f"--people {text!r}: a person index is 0 or more")
    return k


# ----------------------------------------------------------------------------- reading
def item_error(err: BaseException, file: Optional[str], component: str) -> ItemError:
    """An :class:`ItemError` from a reader's exception: its field when the reader names one
    (:class:`SubjectError`, or ``field '...'`` in the message), else ``component``."""
    if isinstance(err, ItemError):
        return err
    if isinstance(err, SubjectError):
        return ItemError(err.path, err.field, err.message)
    message = str(err).splitlines()[0] if str(err) else type(err).__name__
    if not isinstance(err, (InputError, FileNotFoundError)):
        message = short_message(message, library=True)
    if file and message.startswith(f"{file}"):
        message = re.sub(
            r"^\s*(\([^)]*\))?:\s*", lambda m: f"{m.group(1)}: " if m.group(1) else "", message[len(file) :]
        )
    named = getattr(err, "field", None)  # errors that carry their field (silfit's InputError)
    if isinstance(named, str) and named:
        return ItemError(file, named, message)
    found = re.search(r"field(?:\(s\))? '([^']+)'", message) or re.search(r"\((people\[\d+\][^)]*)\)", message)
    return ItemError(file, found.group(1) if found else component, message)


def read_component(component: str, file: Optional[str], fn, *args, **kwargs):
    try:
        return fn(*args, **kwargs)
    except (ValueError, FileNotFoundError, OSError, KeyError, TypeError) as err:
        raise item_error(err, file, component) from None


def read_people(path: Union[str, os.PathLike]) -> List[KeypointSet]:
    """Every person in a keypoint file, in file order, read with
    :func:`silfit.io.keypoints.read_keypoints` (which checks all of them on every call, so once
    person 0 has been read, the first index that fails is past the last person)."""
    people = [read_keypoints(path, person=0)]
    while True:
        try:
            people.append(read_keypoints(path, person=len(people)))
        except ValueError:
            return people


def _largest(people: List[KeypointSet]) -> int:
    """The index ``read_keypoints(..., person="largest")`` picks."""
    return max(range(len(people)), key=lambda i: people[i].visible_area())


def load_item(item: Item, read_masks: bool = True) -> LoadedItem:
    """Read and check one item's keypoints, camera, mask and image (:class:`ItemError` on
    the first problem, naming the file and field); ``read_masks=False`` (keypoint-only runs)
    finds the person's mask file but does not read it."""
    if item.error:
        raise ItemError(item.error.get("file"), item.error.get("field", "input"), item.error.get("message", ""))
    people = read_component("keypoints", item.keypoints, read_people, item.keypoints)
    if item.person == LARGEST:
        k = _largest(people)
    else:
        k = int(item.person)
        if not 0 <= k < len(people):
            raise ItemError(item.keypoints, "people", f"person {k} requested, the file holds {len(people)}")
    mask_file = item.masks.get(str(k)) or (item.masks.get(LARGEST) if k == _largest(people) else None)

    camera = read_component("camera", item.camera, load_camera, item.camera) if item.camera else None
    size = None if camera is None else (camera.width, camera.height)
    image = read_component("image", item.image, read_image, item.image, size) if item.image else None
    if size is None and image is not None:
        size = (image.shape[1], image.shape[0])
    mask = read_component("mask", mask_file, read_mask, mask_file, size) if mask_file and read_masks else None
    if camera is None and image is None and mask is None and mask_file:
        mask = read_component("mask", mask_file, read_mask, mask_file, size)  # the only source of the image size
    if camera is None:
        ref = image if image is not None else mask
        if ref is None:
            raise ItemError(
                item.keypoints, "camera", "no camera: give a camera.json, or an image or mask for the default camera"
            )
        camera = Camera.from_image_size(ref.shape[1], ref.shape[0])
    return LoadedItem(item, people[k], k, len(people), camera, mask, mask_file, image)


# ----------------------------------------------------------------------------- listing
def list_items(
    input: Union[str, os.PathLike],
    people: Union[int, str] = LARGEST,
    masks: Optional[str] = None,
    images: Optional[str] = None,
    camera: Optional[str] = None,
) -> List[Item]:
    """The items of a dataset input (see the module docstring), in a stable order."""
    p = Path(input)
    if p.is_file():
        if masks or images or camera:
            raise InputError(f"{p}: --masks, --images and --camera are for folder inputs; a manifest names its files")
        return _unique(p, _manifest_items(p, people))
    if not p.is_dir():
        raise InputError(f"{p}: dataset input not found (expected a folder or a .jsonl/.csv manifest)")
    if any(f.name.endswith(KEYPOINT_SUFFIX) for f in p.iterdir()):
        return _unique(p, _openpose_items(p, people, masks, images, camera))
    if masks or images or camera:
        raise InputError(f"{p}: --masks, --images and --camera are for OpenPose folders (*{KEYPOINT_SUFFIX})")
    try:
        subjects = list_subjects(p)
    except (SubjectError, FileNotFoundError) as err:
        raise InputError(str(err)) from None
    if not subjects:
        raise InputError(f"{p}: no *{KEYPOINT_SUFFIX} files and no subject folders (keypoints.json) found")
    return _unique(p, _synthetic_items(subjects, people))


def _expand(key: str, keypoints: str, people, masks: Dict[str, str], **files) -> List[Item]:
    """Items of one image under ``people``; ``all`` reads the keypoint file to count them."""
    if people == "all":
        try:
            n = len(read_people(keypoints))
        except (ValueError, FileNotFoundError, OSError) as err:
            return [
                Item(key, keypoints, LARGEST, masks, error=item_error(err, keypoints, "keypoints").to_dict(), **files)
            ]
        return [Item(f"{key}_{k}", keypoints, k, masks, **files) for k in range(n)]
    if people == LARGEST:
        return [Item(key, keypoints, LARGEST, masks, **files)]
    return [Item(f"{key}_{int(people)}", keypoints, int(people), masks, **files)]


def _openpose_items(folder: Path, people, masks: Optional[str], images: Optional[str], camera: Optional[str]):
    for opt, path in (("--masks", masks), ("--images", images)):
        if path and not Path(path).is_dir():
            raise InputError(f"{path}: {opt} folder not found")
    shared_camera, camera_dir = None, None
    if camera:
        if Path(camera).is_dir():
            camera_dir = Path(camera)
        elif Path(camera).is_file():
            shared_camera = camera
        else:
            raise InputError(f"{camera}: --camera file or folder not found")
    elif (folder / "camera.json").is_file():
        shared_camera = os.fspath(folder / "camera.json")
    mask_files = _by_name(masks, (".png",))
    image_files = _by_name(images, IMAGE_SUFFIXES)
    items = []
    for f in sorted(folder.iterdir()):
        if not f.name.endswith(KEYPOINT_SUFFIX):
            continue
        stem = f.name[: -len(KEYPOINT_SUFFIX)]
        person_masks = {}
        if stem in mask_files:
            person_masks[LARGEST] = mask_files[stem]
        for name, path in mask_files.items():
            m = re.fullmatch(re.escape(stem) + r"_(\d+)", name)
            if m:
                person_masks[str(int(m.group(1)))] = path
        cam = shared_camera
        if camera_dir is not None:
            cam = os.fspath(camera_dir / f"{stem}.json")  # missing: the item fails, naming it
        items += _expand(stem, os.fspath(f), people, person_masks, image=image_files.get(stem), camera=cam)
    return items


def _by_name(folder: Optional[str], suffixes) -> Dict[str, str]:
    if not folder:
        return {}
    found = {}
    for f in sorted(Path(folder).iterdir()):
        if f.suffix.lower() in suffixes and f.stem not in found:
            found[f.stem] = os.fspath(f)
    return found


def _synthetic_items(subjects: List[Path], people):
    items = []
    for s in subjects:
        kp, cam, mask, image = (s / SUBJECT_FILES[c] for c in ("keypoints", "camera", "mask", "image"))
        masks = {LARGEST: os.fspath(mask)} if mask.is_file() else {}
        items += _expand(
            s.name,
            os.fspath(kp),
            people,
            masks,
            image=os.fspath(image) if image.is_file() else None,
            camera=os.fspath(cam) if cam.is_file() else None,
        )
    return items


def _manifest_rows(path: Path) -> List[dict]:
    check_file_size(path, MAX_JSON_BYTES, "the manifest")
    data = path.read_bytes()
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as err:
        line = data.count(b"\n", 0, err.start) + 1
        raise InputError(
            f"{path}: line {line}: not UTF-8 text (byte 0x{data[err.start]:02x}); is it a binary file?"
        ) from None
    if path.suffix.lower() == ".csv":
        reader = csv.DictReader(text.splitlines())
        if not reader.fieldnames or "keypoints" not in reader.fieldnames:
            raise InputError(f"{path}: line 1: field 'keypoints': the CSV header needs a keypoints column")
        return [{k: v for k, v in row.items() if k is not None} for row in reader]
    if path.suffix.lower() not in (".jsonl", ".ndjson", ".json"):
        raise InputError(f"{path}: unsupported manifest; expected .jsonl (JSON Lines) or .csv")
    rows = []
    for n, line in enumerate(text.splitlines(), 1):
        if not line.strip():
            continue
        try:
            row = json.loads(line)
        except json.JSONDecodeError as err:
            raise InputError(f"{path}: line {n}: not valid JSON ({err})") from None
        if not isinstance(row, dict):
            raise InputError(f"{path}: line {n}: expected an object with {', '.join(MANIFEST_COLUMNS)}")
        rows.append(row)
    return rows


def _manifest_items(path: Path, people):
    base = path.parent
    items = []
    rows = _manifest_rows(path)
    if not rows:
        raise InputError(f"{path}: the manifest has no rows")
    line0 = 2 if path.suffix.lower() == ".csv" else 1
    for n, row in enumerate(rows, line0):
        unknown = sorted(set(row) - set(MANIFEST_COLUMNS))
        if unknown:
            raise InputError(
                f"{path}: line {n}: field '{unknown[0]}': unknown column (expected {', '.join(MANIFEST_COLUMNS)})"
            )
        for col, value in row.items():
            if value is not None and not isinstance(value, (str, int)) or isinstance(value, bool):
                raise InputError(f"{path}: line {n}: field '{col}': expected a string, got {quoted(value)}")
        get = lambda c: (str(row[c]).strip() or None) if row.get(c) not in (None, "") else None  # noqa: E731
        resolve = lambda c: os.fspath(base / get(c)) if get(c) else None  # noqa: E731
        if not get("keypoints"):
            raise InputError(f"{path}: line {n}: field 'keypoints': missing (every row names a keypoint file)")
        keypoints = resolve("keypoints")
        stem = get("id") or _stem(Path(keypoints))
        person = people
        if get("person"):
            try:
                person = parse_people(get("person"))
            except InputError:
                raise InputError(
                    f"{path}: line {n}: field 'person': expected largest, all or an index, got {quoted(get('person'))}"
                ) from None
        masks = {}
        if get("mask"):
            masks[str(person) if isinstance(person, int) else LARGEST] = resolve("mask")
        row_items = _expand(stem, keypoints, person, masks, image=resolve("image"), camera=resolve("camera"))
        if get("id") and len(row_items) == 1:
            row_items[0].key = get("id")
        items += row_items
    return items


def _stem(keypoints: Path) -> str:
    """A manifest row's default name: the keypoint file's stem without ``_keypoints``, or its
    folder's name for a plain ``keypoints.json`` (the synthetic layout)."""
    stem = keypoints.name.removesuffix(KEYPOINT_SUFFIX).removesuffix(".json")
    return keypoints.parent.name if stem == "keypoints" else stem


def _unique(source: Path, items: List[Item]) -> List[Item]:
    seen = {}
    for it in items:
        if it.key in seen:
            raise InputError(
                f"{source}: two items would write the same output folder {it.key!r} "
                f"({seen[it.key]} and {it.keypoints}); give them distinct ids"
            )
        if it.key.startswith(".") or "/" in it.key or it.key in RESERVED:
            raise InputError(f"{source}: item name {it.key!r} cannot be an output folder name")
        seen[it.key] = it.keypoints
    return items
