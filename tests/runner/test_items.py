"""Dataset inputs: listing items of the three input kinds, and reading one item's files."""

import json
import shutil

import numpy as np
import pytest

from silfit.runner.items import InputError, ItemError, list_items, load_item

from .helpers import SYNTHETIC, openpose_folder, synthetic_copy


def test_openpose_folder_people_masks_cameras(tmp_path):
    root = openpose_folder(tmp_path)
    kw = dict(masks=str(root / "masks"), images=str(root / "images"), camera=str(root / "cameras"))
    largest = list_items(root / "kp", "largest", **kw)
    assert [it.key for it in largest] == ["subject_000", "subject_001", "subject_002"]
    every = list_items(root / "kp", "all", **kw)
    assert [it.key for it in every] == ["subject_000_0", "subject_001_0", "subject_001_1", "subject_002_0"]
    one, other = (load_item(it) for it in every[1:3])
    # person 0 has its mask, the second (keypoint-only) person none; the camera is per image
    assert one.person == 0 and one.people == 2 and one.mask is not None and one.mask.shape == (256, 256)
    assert other.person == 1 and other.mask is None and other.image.shape == (256, 256, 3)
    cam = json.loads((SYNTHETIC / "subject_001" / "camera.json").read_text())
    assert one.camera.fx == pytest.approx(cam["fx"])
    assert not np.allclose(one.keypoints.xy, other.keypoints.xy)
    # an unindexed mask belongs to the largest person, and "largest" picks person 0 here
    shutil.move(root / "masks" / "subject_001_0.png", root / "masks" / "subject_001.png")
    (it,) = [i for i in list_items(root / "kp", "largest", **kw) if i.key == "subject_001"]
    li = load_item(it)
    assert li.person == 0 and li.mask is not None
    assert load_item(list_items(root / "kp", 1, **kw)[1]).mask is None
    # a shared camera file
    shared = list_items(root / "kp", "largest", camera=str(root / "cameras" / "subject_000.json"))
    assert {it.camera for it in shared} == {str(root / "cameras" / "subject_000.json")}


def test_manifest_jsonl_and_csv(tmp_path):
    synthetic_copy(tmp_path / "data", ["subject_000", "subject_001"])
    rows = [
        {
            "keypoints": "data/subject_000/keypoints.json",
            "mask": "data/subject_000/mask.png",
            "camera": "data/subject_000/camera.json",
        },
        {
            "keypoints": "data/subject_001/keypoints.json",
            "image": "data/subject_001/image.png",
            "id": "b",
            "person": "0",
        },
    ]
    (tmp_path / "m.jsonl").write_text("\n".join(json.dumps(r) for r in rows) + "\n")
    (tmp_path / "m.csv").write_text(
        "keypoints,mask,image,camera,person,id\n"
        + "\n".join(
            ",".join(str(r.get(c, "")) for c in ("keypoints", "mask", "image", "camera", "person", "id")) for r in rows
        )
        + "\n"
    )
    for name in ("m.jsonl", "m.csv"):
        items = list_items(tmp_path / name)
        assert [it.key for it in items] == ["subject_000", "b"]
        a, b = (load_item(it) for it in items)
        assert a.mask is not None and b.mask is None and b.image is not None
        assert b.camera.width == 256  # the default camera of the image's size
        assert items[0].keypoints == str(tmp_path / "data/subject_000/keypoints.json")


@pytest.mark.parametrize(
    "text, words",
    [
        ('{"keypoints": "a.json"}\n{"mask": "m.png"}\n', "line 2: field 'keypoints'"),
        ('{"keypoints": "a.json", "colour": "red"}\n', "field 'colour': unknown column"),
        ('{"keypoints": "a.json"}\nnot json\n', "line 2: not valid JSON"),
        ('{"keypoints": "a.json"}\n{"keypoints": "b/a.json"}\n', "same output folder 'a'"),
        ('{"keypoints": "a.json", "person": "two"}\n', "field 'person'"),
        (
            b'{"keypoints": "a.json"}\n\x00\xc2\x01\xff binary',
            "line 2: not UTF-8 text (byte 0xc2); is it a binary file?",
        ),
    ],
)
def test_bad_manifest_is_one_clear_error(tmp_path, text, words):
    (tmp_path / "m.jsonl").write_bytes(text.encode("utf-8") if isinstance(text, str) else text)
    with pytest.raises(InputError) as info:
        list_items(tmp_path / "m.jsonl")
    assert words in str(info.value) and str(tmp_path / "m.jsonl") in str(info.value)


def test_synthetic_dataset_and_item_errors(tmp_path):
    root = synthetic_copy(tmp_path, ["subject_000", "subject_001", "subject_002", "subject_003"])
    (root / "subject_001" / "keypoints.json").write_text('{"people": [{"pose_keypoints_2d": [1, 2]}]}')
    (root / "subject_002" / "camera.json").write_text('{"fx": 100, "fy": 100, "cx": 10}')
    from PIL import Image

    Image.fromarray(np.zeros((10, 12), np.uint8)).save(root / "subject_003" / "mask.png")
    items = list_items(root, "largest")
    assert [it.key for it in items] == ["subject_000", "subject_001", "subject_002", "subject_003"]
    assert load_item(items[0]).mask is not None
    expected = [
        ("subject_001/keypoints.json", "people[0].pose_keypoints_2d"),
        ("subject_002/camera.json", "camera"),
        ("subject_003/mask.png", "mask"),
    ]
    for it, (file, field) in zip(items[1:], expected):
        with pytest.raises(ItemError) as info:
            load_item(it)
        assert info.value.file == str(root / file) and info.value.field == field, info.value
        assert info.value.message and "\n" not in info.value.message
    # a keypoint-only run finds the mask but does not read it
    li = load_item(items[3], read_masks=False)
    assert li.mask is None and li.mask_file == str(root / "subject_003" / "mask.png")
    # with --people all the unreadable file is still one (failing) item
    every = list_items(root, "all")
    assert [it.key for it in every] == ["subject_000_0", "subject_001", "subject_002_0", "subject_003_0"]
    assert every[1].error["field"] == "people[0].pose_keypoints_2d"


def test_whole_input_errors(tmp_path):
    with pytest.raises(InputError, match="not found"):
        list_items(tmp_path / "missing")
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputError, match="no .* found"):
        list_items(tmp_path / "empty")
    root = openpose_folder(tmp_path / "op", names=("subject_000",))
    with pytest.raises(InputError, match="--masks folder not found"):
        list_items(root / "kp", masks=str(tmp_path / "nowhere"))


def test_failure_messages_quote_only_a_short_prefix_of_what_a_file_holds(tmp_path):
    """A manifest may name any file: an item's message quotes at most a short, escaped
    prefix of a string read from it (silfit's readers and library messages alike)."""
    import json

    from silfit.errors import QUOTE_CHARS
    from silfit.runner.items import item_error

    secret = "SECRET\n\x1b[31m" + "x" * 300 + "END"
    kp = {"people": [{"pose_keypoints_2d": [10.0] * 4 + [secret] + [1.0] * 70}]}
    (tmp_path / "kp.json").write_text(json.dumps(kp))
    (tmp_path / "cam.json").write_text(json.dumps({"fx": secret, "fy": 1, "cx": 1, "cy": 1, "width": 9, "height": 9}))
    (tmp_path / "m.jsonl").write_text(
        '{"id": "a", "keypoints": "kp.json"}\n{"id": "b", "keypoints": "kp.json", "camera": "cam.json"}\n'
    )
    messages = []
    for it in list_items(tmp_path / "m.jsonl"):
        with pytest.raises(ItemError) as info:
            load_item(it)
        messages.append(info.value.message)
    try:  # a library's message that quotes the value
        float(secret)
    except ValueError as err:
        messages.append(item_error(err, str(tmp_path / "kp.json"), "keypoints").message)
    for message in messages:
        assert "END" not in message and "\x1b" not in message and "\n" not in message, message
        assert "SECRET\\n\\x1b[31m" in message and " characters)" in message, message
        assert len(message) < 200 and QUOTE_CHARS <= 32
