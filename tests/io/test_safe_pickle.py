"""Restricted unpickling: crafted pickles that try to run code are refused before anything
runs; the official model/prior layouts still load."""

import io
import os
import pickle
import sys
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "body"))
from test_io import official_arrays, write_chumpy_pickle  # noqa: E402

from silfit import load_body_model  # noqa: E402
from silfit.errors import InputError, UnsafeFileError  # noqa: E402
from silfit.priors import load_pose_prior  # noqa: E402
from silfit.io.safe_pickle import RestrictedUnpickler, load_npz, load_pickle  # noqa: E402


def _touch_command(marker: Path) -> str:
    return f"touch {marker}"


class _Reduce:
    """Pickles as ``func(*args)``: what a hostile file does."""

    def __init__(self, func, args):
        self.func, self.args = func, args

    def __reduce__(self):
        return self.func, self.args


def _attacks(marker: Path) -> dict:
    import builtins
    import posix
    import subprocess

    cmd = _touch_command(marker)
    return {
        "os.system": _Reduce(os.system, (cmd,)),
        "posix.system": _Reduce(posix.system, (cmd,)),
        "subprocess.call": _Reduce(subprocess.call, (["touch", str(marker)],)),
        "subprocess.Popen": _Reduce(subprocess.Popen, (["touch", str(marker)],)),
        "builtins.eval": _Reduce(builtins.eval, (f"__import__('os').system({cmd!r})",)),
        "builtins.exec": _Reduce(builtins.exec, (f"open({str(marker)!r}, 'w').close()",)),
        "builtins.getattr": _Reduce(builtins.getattr, (_Reduce(__import__, ("os",)), "system")),
    }


ATTACK_NAMES = list(_attacks(Path("x")))


def _model_with(payload) -> dict:
    data = official_arrays()
    data["bs_style"] = payload  # hidden among real fields, as a tampered download would be
    return data


@pytest.mark.parametrize("protocol", [0, 2, 4])
@pytest.mark.parametrize("name", ATTACK_NAMES)
def test_hostile_model_pickle_is_refused_and_nothing_runs(tmp_path, name, protocol):
    marker = tmp_path / "ran"
    path = tmp_path / "SMPL_NEUTRAL.pkl"
    path.write_bytes(pickle.dumps(_model_with(_attacks(marker)[name]), protocol=protocol))
    with pytest.raises(UnsafeFileError) as info:
        load_body_model(path)
    message = str(info.value)
    assert str(path) in message and "refused" in message and "\n" not in message
    module, func = name.split(".")
    assert func in message  # names the class (module as pickled, e.g. posix or os)
    assert not marker.exists()


@pytest.mark.parametrize("name", ["os.system", "builtins.eval", "subprocess.Popen"])
def test_hostile_pose_prior_is_refused(tmp_path, name):
    marker = tmp_path / "ran"
    path = tmp_path / "gmm_08.pkl"
    rng = np.random.default_rng(0)
    payload = {
        "means": rng.normal(size=(2, 69)),
        "covars": np.stack([np.eye(69)] * 2),
        "weights": _attacks(marker)[name],
    }
    path.write_bytes(pickle.dumps(payload, protocol=2))
    with pytest.raises(UnsafeFileError, match="gmm_08.pkl"):
        load_pose_prior(path)
    assert not marker.exists()


def test_hostile_object_array_in_npz_is_refused(tmp_path):
    marker = tmp_path / "ran"
    arrays = official_arrays()
    arrays["posedirs"] = np.array(_attacks(marker)["os.system"], dtype=object)
    np.savez(tmp_path / "m.npz", **arrays)
    with pytest.raises(UnsafeFileError, match=r"m\.npz.*posedirs.*system"):
        load_body_model(tmp_path / "m.npz")
    assert not marker.exists()
    # and the pose-prior / params readers take no object arrays at all
    np.savez(tmp_path / "p.npz", means=np.array([{"a": 1}], dtype=object))
    with pytest.raises(InputError, match=r"p\.npz.*'means'.*objects"):
        load_npz(tmp_path / "p.npz")


def test_hostile_class_inside_a_chumpy_state_is_refused(tmp_path):
    """A chumpy stand-in keeps its state, but the state's classes are checked too."""
    marker = tmp_path / "ran"
    # GLOBAL chumpy.ch Ch; EMPTY_TUPLE; NEWOBJ; {x: os.system(...)}; BUILD
    inner = pickle.dumps(_attacks(marker)["os.system"], protocol=2)[2:-1]  # strip PROTO and STOP
    data = b"\x80\x02cchumpy.ch\nCh\n)\x81}X\x01\x00\x00\x00x" + inner + b"sb."
    path = tmp_path / "ch.pkl"
    path.write_bytes(data)
    with pytest.raises(UnsafeFileError, match="system"):
        load_pickle(path)
    assert not marker.exists()


def test_python2_names_are_mapped_then_checked(tmp_path):
    marker = tmp_path / "ran"
    # protocol 0 as Python 2 wrote it: GLOBAL '__builtin__ eval'
    cmd = f"__import__('os').system('touch {marker}')"
    data = b"c__builtin__\neval\n(V" + cmd.encode() + b"\ntR."
    path = tmp_path / "py2.pkl"
    path.write_bytes(data)
    with pytest.raises(UnsafeFileError, match="builtins.eval"):
        load_pickle(path)
    assert not marker.exists()
    # while a Python-2 style set of numbers (copy_reg / __builtin__ names) loads
    path.write_bytes(pickle.dumps({"s": {1, 2}, "a": np.arange(3.0)}, protocol=2, fix_imports=True))
    value = load_pickle(path)
    assert value["s"] == {1, 2} and np.array_equal(value["a"], np.arange(3.0))


def test_codecs_encode_is_latin1_only(tmp_path):
    data = b"\x80\x02c_codecs\nencode\nX\x03\x00\x00\x00abcX\x05\x00\x00\x00rot13\x86R."
    path = tmp_path / "b.pkl"
    path.write_bytes(data)
    with pytest.raises(InputError, match=r"b\.pkl.*rot13"):
        load_pickle(path)
    assert RestrictedUnpickler(io.BytesIO(pickle.dumps(b"\x00\xff", protocol=2)), "mem").load() == b"\x00\xff"
    path.write_bytes(pickle.dumps({"b": b"\x00\xff"}, protocol=2))
    assert load_pickle(path)["b"] == b"\x00\xff"


@pytest.mark.parametrize("fmt", ["csc", "csr", "coo"])
def test_official_layouts_load_with_sparse_regressors_and_object_arrays(tmp_path, fmt):
    arrays = official_arrays()
    reference = load_body_model(_savez(tmp_path / "ref.npz", arrays), dtype=torch.float64)
    # a chumpy pickle (stand-ins + sparse regressor), as the official SMPL files are
    write_chumpy_pickle(tmp_path / "SMPL_NEUTRAL.pkl", arrays)
    from_pkl = load_body_model(tmp_path / "SMPL_NEUTRAL.pkl", dtype=torch.float64)
    # a converted .npz whose regressor is a pickled sparse matrix (an object array)
    converted = dict(
        arrays, J_regressor=np.array(getattr(scipy.sparse, f"{fmt}_matrix")(arrays["J_regressor"]), dtype=object)
    )
    from_npz = load_body_model(_savez(tmp_path / "conv.npz", converted), dtype=torch.float64)
    assert torch.allclose(from_pkl.J_regressor, reference.J_regressor)
    assert torch.allclose(from_npz.J_regressor, reference.J_regressor)
    pose = torch.randn(2, 69, dtype=torch.float64) * 0.3
    assert torch.allclose(from_npz(body_pose=pose).vertices, reference(body_pose=pose).vertices)


def test_malformed_sparse_state_is_a_clean_error(tmp_path):
    m = scipy.sparse.csc_matrix(official_arrays()["J_regressor"])
    data = pickle.dumps(m, protocol=2).replace(b"indptr", b"indpXX")
    arrays = dict(official_arrays())
    arrays.pop("J_regressor")
    body = pickle.dumps(arrays, protocol=2)
    # splice the broken matrix in as the regressor: {..., 'J_regressor': <broken>}
    path = tmp_path / "m.pkl"
    path.write_bytes(body[:-1] + b"X\x0b\x00\x00\x00J_regressor" + data[2:-1] + b"s.")
    with pytest.raises(InputError, match=r"m\.pkl.*'J_regressor'.*malformed"):
        load_body_model(path)


def _savez(path, arrays):
    np.savez(path, **arrays)
    return path


def test_a_pickle_cannot_allocate_more_than_it_holds(tmp_path):
    """``numpy.ndarray(shape)`` and ``_reconstruct(ndarray, shape, ...)`` would allocate any
    shape the file names; the first is refused, the second always starts at shape (0,)."""
    path = tmp_path / "big.pkl"
    path.write_bytes(b"\x80\x02cnumpy\nndarray\nJ\x00\xe1\xf5\x05J\x00\xe1\xf5\x05\x86\x85R.")  # ndarray((1e8, 1e8))
    with pytest.raises(InputError, match=r"big\.pkl.*ndarray may only appear"):
        load_pickle(path)
    path.write_bytes(
        b"\x80\x02cnumpy._core.multiarray\n_reconstruct\ncnumpy\nndarray\nJ\x00\xe1\xf5\x05\x85C\x01b\x87R."
    )
    assert load_pickle(path).shape == (0,)
    path.write_bytes(b"\x80\x02c__builtin__\nbytearray\nJ\x00\xca\x9a;\x85R.")  # bytearray(10**9)
    with pytest.raises(UnsafeFileError, match="builtins.bytearray"):
        load_pickle(path)
    path.write_bytes(b"\x80\x05\x96" + (2**40).to_bytes(8, "little") + b".")  # a 1 TiB bytearray8 in 12 bytes
    with pytest.raises(InputError, match=r"big\.pkl.*malformed"):
        load_pickle(path)
    for protocol in (2, 4, 5):  # while real arrays of every protocol still load
        path.write_bytes(pickle.dumps({"a": np.arange(12.0).reshape(3, 4), "s": np.float32(2)}, protocol=protocol))
        value = load_pickle(path)
        assert np.array_equal(value["a"], np.arange(12.0).reshape(3, 4)) and value["s"] == 2


def _nested_by_memo(depth: int, width: int = 10):
    """A list nested ``depth`` deep, each level holding the next ``width`` times: pickled as
    one list and memo references, a few hundred bytes for ``width ** depth`` numbers."""
    value = [0.0] * width
    for _ in range(depth - 1):
        value = [value] * width
    return value


def test_a_memo_bomb_is_refused_before_anything_is_unpickled(tmp_path, monkeypatch):
    """The issue's model file: v_template nested 10 deep through memo references (10**10
    floats in a 1 KB pickle) is refused with the file and the field, before unpickling."""
    path = tmp_path / "SMPL_NEUTRAL.pkl"
    path.write_bytes(pickle.dumps(dict(official_arrays(), v_template=_nested_by_memo(10)), protocol=2))
    assert len(pickle.dumps(_nested_by_memo(10), protocol=2)) < 1024

    def never(self):
        raise AssertionError("unpickled a refused file")

    monkeypatch.setattr(RestrictedUnpickler, "load", never)
    with pytest.raises(InputError) as info:
        load_body_model(path)
    message = str(info.value)
    assert message.startswith(str(path)) and "'v_template'" in message and "MiB" in message and "\n" not in message
    assert info.value.field == "v_template"


def test_memo_reuse_and_nesting_within_the_bounds_still_load(tmp_path):
    path = tmp_path / "p.pkl"
    shared = np.arange(6.0)
    path.write_bytes(pickle.dumps({"a": shared, "b": shared, "n": _nested_by_memo(5)}, protocol=2))  # 10**5 floats
    value = load_pickle(path)
    assert value["a"] is value["b"] and np.asarray(value["n"]).shape == (10,) * 5
    cyclic = [1.0]
    cyclic.append(cyclic)
    path.write_bytes(pickle.dumps(cyclic, protocol=2))
    value = load_pickle(path)
    assert value[1] is value  # a cycle is small; whoever reads it as an array gets numpy's own error


def test_a_pickle_nested_too_deeply_is_refused(tmp_path):
    from silfit.io.safe_pickle import MAX_DEPTH

    path = tmp_path / "deep.pkl"
    path.write_bytes(pickle.dumps({"v_template": _nested_by_memo(MAX_DEPTH + 5, width=1)}, protocol=2))
    with pytest.raises(InputError, match=r"deep\.pkl.*nested 3\d deep.*more than the 32"):
        load_pickle(path)
    # and ten thousand levels (where a recursive reader would overflow its stack) the same way
    path.write_bytes(b"\x80\x02" + b"]" * 10_000 + b"a" * 9_999 + b".")
    with pytest.raises(InputError, match=r"deep\.pkl.*nested 10000 deep"):
        load_pickle(path)
