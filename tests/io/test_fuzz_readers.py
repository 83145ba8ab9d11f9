"""Property-based fuzzing of every input reader: whatever the file holds (malformed JSON,
wrong types and shapes, NaN/inf, huge and negative numbers, truncated and random bytes,
odd PNG modes and sizes, hostile pickles), the reader either returns a valid object or
raises :class:`silfit.errors.InputError` naming the file, on one line. Nothing else escapes."""

import io
import json
import os
import pickle
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "body"))
from test_io import official_arrays  # noqa: E402

from silfit.body.io import load_model_arrays  # noqa: E402
from silfit.camera import Camera, load_camera  # noqa: E402
from silfit.io.fit import read_fit  # noqa: E402
from silfit.errors import InputError  # noqa: E402
from silfit.io.keypoints import KeypointSet, read_keypoints  # noqa: E402
from silfit.io.safe_pickle import MAX_DEPTH, expansion_limit, load_pickle  # noqa: E402
from silfit.silhouette import read_mask  # noqa: E402


def read_params(path):
    """The fit-file reader as ``silfit render`` uses it: any parameters present, and the stored camera."""
    fit = read_fit(path, require=())
    return fit.params, fit.camera


#: Examples per reader (kept small for CI; SILFIT_FUZZ_EXAMPLES=2000 for a long local run).
FUZZ = settings(
    max_examples=int(os.environ.get("SILFIT_FUZZ_EXAMPLES", "60")),
    deadline=None,
    suppress_health_check=list(HealthCheck),
    database=None,
)

# ----------------------------------------------------------------------------- strategies
numbers = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.integers(min_value=-(10**30), max_value=10**30),
    st.sampled_from([0, 1, -1, 0.5, 1e30, -1e30, 10**400, 2**63, 320, 240, 1e-300]),
)
scalars = st.one_of(numbers, st.none(), st.booleans(), st.text(max_size=8))
json_values = st.recursive(
    scalars,
    lambda inner: st.lists(inner, max_size=6) | st.dictionaries(st.text(max_size=6), inner, max_size=4),
    max_leaves=30,
)


def _mutated(valid: list, values):
    """``valid`` with a few entries replaced by ``values``."""
    edits = st.lists(st.tuples(st.integers(0, len(valid) - 1), values), max_size=3)
    return edits.map(lambda es: [dict(es).get(i, v) for i, v in enumerate(valid)])


_VALID_KP = [float(v) for row in np.random.default_rng(0).uniform(1, 300, (25, 3)) for v in (row[0], row[1], 0.9)]
_VALID_CAMERA = {"fx": 500.0, "fy": 500.0, "cx": 160.0, "cy": 120.0, "width": 320, "height": 240}


def _keypoint_docs():
    row = st.lists(numbers, min_size=0, max_size=80) | st.lists(st.lists(numbers, min_size=2, max_size=4), max_size=30)
    flat = st.one_of(_mutated(_VALID_KP, scalars), row, json_values, st.lists(scalars, min_size=75, max_size=75))
    person = st.fixed_dictionaries({"pose_keypoints_2d": flat}) | json_values
    return st.one_of(
        st.fixed_dictionaries({"people": st.lists(person, max_size=3) | json_values}),
        st.fixed_dictionaries({"keypoints": flat}),
        st.lists(st.fixed_dictionaries({"keypoints": flat}) | json_values, max_size=3),
        flat,
        json_values,
    )


def _as_bytes(doc, cut, junk: bytes) -> bytes:
    text = json.dumps(doc).encode()  # NaN / Infinity are written as such, as some tools do
    if cut is not None:
        text = text[: int(cut * len(text))]
    return text + junk


byte_tails = st.one_of(st.just(b""), st.binary(max_size=16))
cuts = st.one_of(st.none(), st.floats(0, 1))


def _check_clean(call, path: Path):
    try:
        value = call()
    except InputError as err:
        message = str(err)
        assert message.startswith(str(path)) and "\n" not in message, message
        event("clean error")
        return None
    event("read")
    return value


# ----------------------------------------------------------------------------- readers
@FUZZ
@given(doc=_keypoint_docs(), cut=cuts, junk=byte_tails, person=st.sampled_from(["largest", 0, 1, -1, 5]))
def test_keypoint_reader(doc, cut, junk, person):
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "kp.json"
        path.write_bytes(_as_bytes(doc, cut, junk))
        result = _check_clean(lambda: read_keypoints(path, person=person), path)
        if result is not None:
            assert isinstance(result, KeypointSet) and np.isfinite(result.xy).all() and (result.conf > 0).any()


@FUZZ
@given(
    fields=st.fixed_dictionaries(
        {}, optional={k: numbers | scalars for k in ("fx", "fy", "cx", "cy", "width", "height")}
    ),
    extra=st.none() | json_values,
    cut=cuts,
    junk=byte_tails,
)
def test_camera_reader(fields, extra, cut, junk):
    doc = (
        {**_VALID_CAMERA, **fields} if extra is None else fields if not isinstance(extra, dict) else {**extra, **fields}
    )
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "camera.json"
        path.write_bytes(_as_bytes(doc, cut, junk))
        camera = _check_clean(lambda: load_camera(path), path)
        if camera is not None:
            assert isinstance(camera, Camera) and camera.width * camera.height <= 8192**2


_MODES = ["1", "L", "P", "RGB", "RGBA", "LA", "I", "I;16", "F", "CMYK"]


@FUZZ
@given(
    h=st.integers(1, 12),
    w=st.integers(1, 12),
    mode=st.sampled_from(_MODES),
    fmt=st.sampled_from(["PNG", "TIFF", "BMP", "JPEG"]),
    seed=st.integers(0, 2**16),
    cut=cuts,
    junk=byte_tails,
    size=st.one_of(st.none(), st.tuples(st.integers(1, 12), st.integers(1, 12))),
)
def test_mask_reader(h, w, mode, fmt, seed, cut, junk, size):
    from PIL import Image

    rng = np.random.default_rng(seed)
    pixels = (rng.random((h, w)) > 0.5).astype(np.uint8) * 255
    img = Image.fromarray(pixels).convert(mode)
    buf = io.BytesIO()
    try:
        img.save(buf, format=fmt)
    except (OSError, ValueError, KeyError):  # a mode the format cannot hold
        img.convert("L").save(buf, format=fmt)
    data = buf.getvalue()
    if cut is not None:
        data = data[: int(cut * len(data))]
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / f"mask.{fmt.lower()}"
        path.write_bytes(data + junk)
        mask = _check_clean(lambda: read_mask(path, size=size), path)
        if mask is not None:
            assert mask.dtype == bool and mask.ndim == 2 and mask.any() and not mask.all()


arrays = st.one_of(
    st.builds(lambda shape, fill: np.full(shape, fill), st.lists(st.integers(0, 4), max_size=3), numbers),
    st.builds(lambda v: np.array(v, dtype=object), json_values),
    json_values,
)


@FUZZ
@given(
    fields=st.dictionaries(
        st.sampled_from(
            [
                "betas",
                "body_pose",
                "global_orient",
                "transl",
                "camera_intrinsics",
                "image_size",
                "layout",
                "camera",
                "x",
            ]
        ),
        arrays,
        max_size=6,
    ),
    as_json=st.booleans(),
    cut=cuts,
    junk=byte_tails,
)
def test_fit_output_reader(fields, as_json, cut, junk):
    with tempfile.TemporaryDirectory() as d:
        if as_json:
            path = Path(d) / "params.json"
            doc = {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in fields.items()}
            try:
                path.write_bytes(_as_bytes(doc, cut, junk))
            except (TypeError, ValueError):  # not JSON-serialisable: write junk instead
                path.write_bytes(junk)
        else:
            path = Path(d) / "params.npz"
            buf = io.BytesIO()
            np.savez(
                buf,
                **{k: np.asarray(v, dtype=object) if not isinstance(v, np.ndarray) else v for k, v in fields.items()},
            )
            data = buf.getvalue()
            path.write_bytes((data if cut is None else data[: int(cut * len(data))]) + junk)
        result = _check_clean(lambda: read_params(path), path)
        if result is not None:
            params, camera = result
            assert params and all(np.isfinite(v).all() for v in params.values())
            assert camera is None or isinstance(camera, Camera)


_FIELDS = [
    "v_template",
    "f",
    "shapedirs",
    "posedirs",
    "J_regressor",
    "weights",
    "kintree_table",
    "joint_names",
    "landmark_regressor",
    "landmark_names",
    "meta_json",
]


@FUZZ
@given(
    replace=st.dictionaries(st.sampled_from(_FIELDS), arrays, max_size=3),
    drop=st.lists(st.sampled_from(_FIELDS), max_size=2),
    as_pickle=st.booleans(),
    flip=st.lists(st.tuples(st.floats(0, 1), st.integers(0, 255)), max_size=4),
    cut=cuts,
)
def test_model_reader(replace, drop, as_pickle, flip, cut):
    model = dict(official_arrays())
    model.update(replace)
    for k in drop:
        model.pop(k, None)
    buf = io.BytesIO()
    if as_pickle:
        pickle.dump(model, buf, protocol=2)
    else:
        np.savez(buf, **{k: v if isinstance(v, np.ndarray) else np.asarray(v, dtype=object) for k, v in model.items()})
    data = bytearray(buf.getvalue())
    for where, value in flip:  # corrupt a few bytes
        data[int(where * (len(data) - 1))] = value
    if cut is not None:
        data = data[: int(cut * len(data))]
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / ("SMPL_NEUTRAL.pkl" if as_pickle else "SMPL_NEUTRAL.npz")
        path.write_bytes(bytes(data))
        arrays_out = _check_clean(lambda: load_model_arrays(path), path)
        if arrays_out is not None:
            assert np.isfinite(arrays_out.v_template).all() and arrays_out.num_joints >= 1


def _expanded_size(value) -> tuple:
    """Bytes (8 per number, string and container) and nesting of ``value``, every reference
    to a shared object counted again (what ``numpy.asarray`` would copy); a reference back
    into a cycle counts 8 bytes. An independent count, to check the unpickler's bound."""
    done: dict = {}

    def walk(v, path: frozenset) -> tuple:
        if not isinstance(v, (list, tuple, dict, set, frozenset)):
            return 8, 0
        if id(v) in path:
            return 8, 0
        if id(v) in done:
            return done[id(v)]
        items = [x for kv in v.items() for x in kv] if isinstance(v, dict) else list(v)
        inner = [walk(x, path | {id(v)}) for x in items]
        done[id(v)] = result = (8 + sum(b for b, _ in inner), 1 + max((d for _, d in inner), default=0))
        return result

    return walk(value, frozenset())


@st.composite
def _object_graphs(draw):
    """Lists that hold numbers and each other: shared (pickled as memo references), nested
    in chains, in cycles; the first is the value pickled."""
    n = draw(st.integers(1, 40))
    nodes = [[] for _ in range(n)]
    if draw(st.booleans()):  # a chain, each list holding the next ``width`` times: the memory bomb
        width = draw(st.integers(1, 12))
        for i in range(n - 1):
            nodes[i].extend([nodes[i + 1]] * width)
        nodes[-1].extend([0.5] * width)
        return nodes[0]
    for i, node in enumerate(nodes):
        for _ in range(draw(st.integers(0, 12))):
            kind = draw(st.sampled_from(["number", "later", "later", "any"]))
            if kind == "number" or (kind == "later" and i == n - 1):
                node.append(draw(st.floats(allow_nan=False) | st.integers(-(2**40), 2**40)))
            else:
                low = i + 1 if kind == "later" else 0  # "later": a DAG (nesting, memo reuse); "any": cycles too
                node.append(nodes[draw(st.integers(low, n - 1))])
    if draw(st.booleans()):
        nodes[0] = tuple(nodes[0]) if draw(st.booleans()) else {"v_template": nodes[0], "f": list(range(3))}
    return nodes[0]


@FUZZ
@given(
    value=_object_graphs(),
    protocol=st.integers(0, 5),
    flip=st.lists(st.tuples(st.floats(0, 1), st.integers(0, 255)), max_size=2),
)
def test_pickle_memo_and_nesting_are_bounded(value, protocol, flip):
    """Whatever shared, nested or cyclic structure a pickle holds (and a few flipped bytes),
    the restricted unpickler returns a value within its bounds, or refuses the file cleanly."""
    data = bytearray(pickle.dumps(value, protocol=protocol))
    for where, byte in flip:
        data[int(where * (len(data) - 1))] = byte
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "model.pkl"
        path.write_bytes(bytes(data))
        result = _check_clean(lambda: load_pickle(path), path)
    if result is not None:
        size, depth = _expanded_size(result)
        assert size <= expansion_limit(len(data)) and depth <= MAX_DEPTH
    elif not flip:  # an intact pickle is refused only for its size or nesting
        size, depth = _expanded_size(value)
        assert size > expansion_limit(len(data)) or depth > MAX_DEPTH
        event("refused: too large" if size > expansion_limit(len(data)) else "refused: nested too deeply")


@pytest.mark.parametrize("reader", [read_keypoints, load_camera, read_mask, read_params, load_model_arrays])
def test_missing_files_are_file_not_found(tmp_path, reader):
    suffix = {read_mask: ".png", read_params: ".npz", load_model_arrays: ".pkl"}.get(reader, ".json")
    with pytest.raises(FileNotFoundError, match="nothere"):
        reader(tmp_path / f"nothere{suffix}")
