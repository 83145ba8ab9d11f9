"""Restricted unpickling: the only way silfit reads a pickle (model files, pose priors,
object arrays inside ``.npz`` files).

A pickle is a program: every class or function it names is looked up by the unpickler's
``find_class`` and may then be called. :class:`RestrictedUnpickler` allows exactly what
the official files need and refuses everything else **before it is called**, with an
:class:`~silfit.errors.UnsafeFileError` naming the file and the class:

* numpy's array reconstruction (``_reconstruct``, ``_frombuffer``, ``scalar``,
  ``ndarray``, ``dtype``; under ``numpy.core`` and ``numpy._core``), with ``ndarray``
  usable only as ``_reconstruct``'s argument and ``_reconstruct`` only at shape ``(0,)``,
  so a file cannot allocate more memory than it holds data for;
* ``copyreg._reconstructor`` (how protocol-2 pickles rebuild objects; it can only
  rebuild allowed classes, since its arguments come through the same check);
* ``_codecs.encode`` for latin-1 only (how Python 3 writes ``bytes`` at protocol 2);
* a few inert builtins (``object``, ``set``, ``frozenset``, ``complex``);
* scipy's sparse matrices (``csc``, ``csr``, ``coo``; ``*_matrix`` and ``*_array``) and
  every chumpy class: both become *stand-ins* that only keep the pickled state;
  :func:`to_numpy` turns them into dense arrays (the sparse ones through scipy's own
  format checks). No scipy or chumpy object is ever built from a file's state.

Before anything is unpickled, :func:`_check_bounds` runs the opcodes on a model of the
unpickler's stack and memo (building nothing) and refuses a pickle whose value, counting
every reference to a shared object again (as ``numpy.asarray`` on nested lists would copy
it), exceeds ``MAX_EXPANSION`` times its size plus ``MAX_EXPANSION_EXTRA`` bytes, or
whose objects nest more than ``MAX_DEPTH`` deep: a 1 KB pickle of lists nested 10 deep
through memo references (10**10 floats) is refused, naming the file and the field.

Python 2 names (``copy_reg``, ``__builtin__``) are mapped to their Python 3 names first,
as the standard unpickler does.
"""

from __future__ import annotations

import _compat_pickle
import builtins
import copyreg
import importlib
import io
import os
import pickle
import pickletools
import warnings
import zipfile
from typing import Any, Optional, Union

import numpy as np
import scipy.sparse

from ..errors import InputError, UnsafeFileError, cut_quotes, quoted

__all__ = ["ChumpyStandIn", "SparseStandIn", "RestrictedUnpickler", "load_pickle", "load_npz", "to_numpy"]

#: Largest pickle or ``.npz`` file read (bytes). Official SMPL-X pickles are a few hundred MB.
MAX_FILE_BYTES = 4 * 1024**3
#: Most nesting of objects in a pickle (official model files: under 10).
MAX_DEPTH = 32
#: A pickle may unpack to at most ``MAX_EXPANSION`` times its size plus ``MAX_EXPANSION_EXTRA``
#: bytes, every reference to a shared (memo) object counted again and every number and
#: object 8 bytes: what a consumer that copies the value (``numpy.asarray``) allocates.
MAX_EXPANSION = 8
MAX_EXPANSION_EXTRA = 64 * 1024**2


class _StandIn:
    """An object a pickle may build: accepts any arguments, keeps the pickled state and
    nothing else (no method of it can be replaced by the state)."""

    def __init__(self, *args, **kwargs):
        pass

    def __setstate__(self, state):
        self.__dict__["_state"] = state


class ChumpyStandIn(_StandIn):
    """Replaces any chumpy class while unpickling."""

    def to_array(self, _depth: int = 0) -> np.ndarray:
        state = self.__dict__.get("_state")
        if isinstance(state, dict):
            for key in ("x", "a", "r"):
                if key in state:
                    return to_numpy(state[key], _depth + 1)
        raise ValueError("a chumpy object in the file holds no array ('x') this loader can read")


class SparseStandIn(_StandIn):
    """Replaces scipy's sparse matrix classes while unpickling; knows its format (``csc``,
    ``csr`` or ``coo``)."""

    format = ""

    def to_array(self, _depth: int = 0) -> np.ndarray:
        state = self.__dict__.get("_state")
        if not isinstance(state, dict):
            raise ValueError(f"a sparse {self.format} matrix in the file has no readable state")
        shape = state.get("_shape", state.get("shape"))
        arr = lambda key: np.asarray(to_numpy(state[key], _depth + 1))  # noqa: E731
        try:
            shape = tuple(int(s) for s in shape)
            if len(shape) != 2 or min(shape) < 0 or shape[0] * shape[1] > 2**31:
                raise ValueError(f"shape {shape}")
            if self.format == "coo":
                rows, cols = (arr("row"), arr("col")) if "row" in state else tuple(state["coords"])  # scipy < / >= 1.13
                parts = (arr("data"), (np.asarray(to_numpy(rows, _depth + 1)), np.asarray(to_numpy(cols, _depth + 1))))
                matrix = scipy.sparse.coo_matrix(parts, shape=shape)
            else:
                parts = (arr("data"), arr("indices"), arr("indptr"))
                matrix = getattr(scipy.sparse, f"{self.format}_matrix")(parts, shape=shape)
                matrix.check_format(full_check=True)
            return np.asarray(matrix.toarray())
        except (KeyError, TypeError, ValueError, IndexError) as err:
            raise ValueError(
                f"a sparse {self.format} matrix in the file is malformed ({type(err).__name__}: {err})"
            ) from None


def _sparse(fmt: str) -> type:
    return type(f"Sparse_{fmt}", (SparseStandIn,), {"format": fmt})


_SPARSE = {fmt: _sparse(fmt) for fmt in ("csc", "csr", "coo")}


def _latin1_encode(text, encoding="latin1", errors="strict"):
    """``_codecs.encode`` as protocol-2 pickles use it (``bytes`` objects), latin-1 only."""
    name = encoding.replace("-", "").replace("_", "").lower() if isinstance(encoding, str) else None
    if name not in ("latin1", "iso88591") or not isinstance(text, str):
        raise pickle.UnpicklingError(f"_codecs.encode with encoding {quoted(encoding)} is not allowed")
    return text.encode("latin1", errors)


def _numpy_core(submodule: str, name: str):
    try:
        module = importlib.import_module(f"numpy._core.{submodule}")
    except ImportError:  # numpy 1.x
        module = importlib.import_module(f"numpy.core.{submodule}")
    return getattr(module, name)


class _NdarrayType:
    """Stands for ``numpy.ndarray`` where a pickle names it: as the argument of
    ``_reconstruct`` (how numpy pickles arrays). Calling it (which would allocate an array
    of any shape the file asks for) is refused."""

    def __new__(cls, *args, **kwargs):
        raise pickle.UnpicklingError("numpy.ndarray may only appear as the argument of numpy's _reconstruct")


def _reconstruct(subtype, shape, dtype):
    """numpy's ``_reconstruct`` for plain arrays only, always at shape ``(0,)`` (numpy
    pickles give ``(0,)``; the real shape arrives with the data, and numpy checks the
    two agree), so a file cannot make it allocate more than it holds."""
    if subtype is not _NdarrayType:
        raise pickle.UnpicklingError(f"_reconstruct of {getattr(subtype, '__name__', subtype)!r} is not allowed")
    return _numpy_core("multiarray", "_reconstruct")(np.ndarray, (0,), dtype)


def _allowed() -> dict:
    table = {
        ("copyreg", "_reconstructor"): copyreg._reconstructor,
        ("_codecs", "encode"): _latin1_encode,
        ("numpy", "ndarray"): _NdarrayType,
        ("numpy", "dtype"): np.dtype,
    }
    for core in ("numpy.core", "numpy._core"):
        table[(f"{core}.multiarray", "_reconstruct")] = _reconstruct
        table[(f"{core}.multiarray", "scalar")] = _numpy_core("multiarray", "scalar")
        table[(f"{core}.numeric", "_frombuffer")] = _numpy_core("numeric", "_frombuffer")
    for name in ("object", "set", "frozenset", "complex"):
        table[("builtins", name)] = getattr(builtins, name)
    return table


_ALLOWED = _allowed()


def _py3_name(module: str, name: str) -> tuple[str, str]:
    if (module, name) in _compat_pickle.NAME_MAPPING:
        return _compat_pickle.NAME_MAPPING[(module, name)]
    return _compat_pickle.IMPORT_MAPPING.get(module, module), name


class RestrictedUnpickler(pickle.Unpickler):
    """``pickle.Unpickler`` whose ``find_class`` allows only the module's allow-list;
    ``source`` (the file) and ``what`` (e.g. ``"an SMPL model"``) go into the error."""

    def __init__(self, file, source: str, what: str = "this file"):
        super().__init__(file, encoding="latin1")
        self.source, self.what = source, what

    def find_class(self, module: str, name: str):
        module, name = _py3_name(module, name)
        if module.split(".")[0] == "chumpy":
            return ChumpyStandIn
        if module.split(".")[:2] == ["scipy", "sparse"] and name[:3] in _SPARSE and name[3:] in ("_matrix", "_array"):
            return _SPARSE[name[:3]]
        if (module, name) in _ALLOWED:
            return _ALLOWED[(module, name)]
        raise UnsafeFileError(
            self.source,
            f"refused to unpickle '{module}.{name}': not one of the classes {self.what} needs "
            "(numpy arrays, scipy sparse matrices, chumpy arrays); the file may have been tampered with",
            field=f"{module}.{name}",
        )

    def persistent_load(self, pid):
        raise UnsafeFileError(self.source, "refused a pickle persistent id (not used by model files)")


def _check_size(path: str) -> None:
    size = os.path.getsize(path)
    if size > MAX_FILE_BYTES:
        raise InputError(
            path, f"file is {size / 1024**3:.1f} GiB, more than the {MAX_FILE_BYTES / 1024**3:.0f} GiB silfit reads"
        )


def load_pickle(path: Union[str, os.PathLike], what: str = "silfit input") -> Any:
    """Unpickle ``path`` with :class:`RestrictedUnpickler` (latin-1 for Python 2 pickles).

    Raises :class:`UnsafeFileError` for a refused class, :class:`InputError` for any other
    unreadable pickle, ``FileNotFoundError`` for a missing file."""
    source = os.fspath(path)
    if not os.path.isfile(source):
        raise FileNotFoundError(f"{source}: file not found")
    _check_size(source)
    with open(source, "rb") as fh:
        data = fh.read()
    return _unpickle(data, source, what)


class _Node:
    """A container or object the pickle builds, as :func:`_check_bounds` sees it: its own
    bytes, what it holds and the opcode that made it. Leaves are not nodes: a short string
    is itself (a possible dict key, for the message), anything else an int (its bytes)."""

    __slots__ = ("own", "kids", "kind")

    def __init__(self, own: int, kids: list, kind: str):
        self.own, self.kids, self.kind = own, kids, kind


def _leaf_size(leaf) -> int:
    return 8 + len(leaf) if isinstance(leaf, str) else leaf


_MARK = object()
#: Opcodes that add what they pop to the object below them (the same object stays on the stack).
_IN_PLACE = {"APPEND", "APPENDS", "SETITEM", "SETITEMS", "ADDITEMS", "BUILD"}
_GETS = {"GET", "BINGET", "LONG_BINGET"}
_PUTS = {"PUT", "BINPUT", "LONG_BINPUT"}
#: What opcodes push that holds nothing else (a leaf of the value).
_SCALARS = {"int", "int_or_bool", "bytes_or_str", "bytes", "bytearray", "None", "bool", "str", "float"}


def _effect(op) -> tuple:
    """(items popped below the MARK or None when it takes no MARK, items popped, whether it
    pushes, whether what it pushes is a scalar)."""
    before = [s.name for s in op.stack_before]
    after = [s.name for s in op.stack_after]
    return (
        before.index("mark") if "mark" in before else None,
        len(before),
        bool(after),
        bool(after) and after[0] in _SCALARS,
    )


_EFFECTS = {op.name: _effect(op) for op in pickletools.opcodes}


def _leaf_bytes(arg) -> int:
    return 8 + (len(arg) if isinstance(arg, (str, bytes, bytearray)) else 0)


def _simulate(data: bytes) -> Any:
    """Run the pickle's opcodes on a model of its stack and memo (nothing is built): the
    value the pickle would return, as :class:`_Node` objects and leaves, with every memo
    reference pointing at the same node. Raises ``ValueError`` for a malformed pickle."""
    stack: list = []
    memo: dict = {}
    push = stack.append

    def pop(n: int) -> list:
        if n > len(stack):
            raise ValueError("stack underflow")
        items = stack[len(stack) - n :]
        del stack[len(stack) - n :]
        if _MARK in items:
            raise ValueError("a MARK where an object was expected")
        return items

    def pop_to_mark() -> list:
        for i in range(len(stack) - 1, -1, -1):
            if stack[i] is _MARK:
                items = stack[i + 1 :]
                del stack[i:]
                return items
        raise ValueError("no MARK on the stack")

    with warnings.catch_warnings():  # protocol 0's string escapes, read once here and again by the unpickler
        warnings.simplefilter("ignore", DeprecationWarning)
        for op, arg, _pos in pickletools.genops(data):
            name = op.name
            below_mark, count, pushes, scalar = _EFFECTS[name]
            if scalar and not count:  # a number or a string: the commonest opcodes
                if type(arg) is str and len(arg) <= 64:
                    push(arg)  # a possible dict key (the str genops made: nothing new is kept)
                else:
                    push(8 + len(arg) if isinstance(arg, (str, bytes, bytearray)) else 8)
            elif name == "MARK":
                push(_MARK)
            elif name in _PUTS or name == "MEMOIZE":
                if not stack or stack[-1] is _MARK:
                    raise ValueError("memo store with an empty stack")
                memo[len(memo) if name == "MEMOIZE" else arg] = stack[-1]
            elif name in _GETS:
                if arg not in memo:
                    raise ValueError(f"memo key {arg} not found")
                push(memo[arg])
            elif name == "DUP":
                stack.extend(pop(1) * 2)
            elif name == "STOP":
                (root,) = pop(1)
                return root
            elif name in ("PROTO", "FRAME", "READONLY_BUFFER"):
                continue
            else:
                if below_mark is None:
                    taken = pop(count)
                else:
                    sliced = pop_to_mark()
                    taken = pop(below_mark) + sliced
                if name in _IN_PLACE:
                    target = taken[0]
                    if not isinstance(target, _Node):
                        raise ValueError(f"{name} on a number or string")
                    target.kids.extend(taken[1:])
                    push(target)
                elif pushes:  # (POP and POP_MARK push nothing)
                    push(_Node(_leaf_bytes(arg), taken, name))
    raise ValueError("no STOP opcode")


def _expanded(root) -> dict:
    """Bytes and depth of every node below ``root``, each reference to a shared (memo)
    object counted again, as a consumer that copies the value (``numpy.asarray`` on
    nested lists) would; a reference back into a cycle counts 8 bytes. Iterative: the
    nesting may be deep."""
    sizes: dict = {}  # id(node) -> (bytes, depth); None while being visited
    todo = [root]
    while todo:
        node = todo[-1]
        key = id(node)
        if key not in sizes:  # first visit: its nodes first
            sizes[key] = None
            todo.extend(k for k in node.kids if type(k) is _Node and id(k) not in sizes)
            continue
        if sizes[key] is not None:  # reached again through another reference: done
            todo.pop()
            continue
        total, depth = node.own, 0
        for k in node.kids:
            kind = type(k)
            if kind is int:
                total += k
            elif kind is str:
                total += 8 + len(k)
            else:
                got = sizes.get(id(k))
                if got is None:  # a reference back into a cycle
                    total += 8
                else:
                    total += got[0]
                    depth = max(depth, got[1])
        sizes[key] = (total, depth + 1)
        todo.pop()
    return sizes


def _top_field(root, sizes: dict, measure: int) -> Optional[str]:
    """The top-level dict key whose value is largest (``measure`` 0) or deepest (1), for
    the error message; ``None`` when the value is not a dict with string keys."""
    if not isinstance(root, _Node) or root.kind not in ("EMPTY_DICT", "DICT"):
        return None
    best, name = -1, None
    for k, v in zip(root.kids[0::2], root.kids[1::2]):
        size = sizes[id(v)][measure] if isinstance(v, _Node) else (_leaf_size(v), 0)[measure]
        if isinstance(k, str) and size > best:
            best, name = size, k
    return name


def expansion_limit(data_bytes: int) -> int:
    """Most bytes a pickle of ``data_bytes`` may unpack to (see :data:`MAX_EXPANSION`)."""
    return MAX_EXPANSION * data_bytes + MAX_EXPANSION_EXTRA


def _check_bounds(data: bytes, source: str, what: str) -> None:
    """Refuse, before anything is unpickled, a pickle that is malformed (every length
    prefix must lie within the data), nested deeper than :data:`MAX_DEPTH`, or whose value,
    counting each reference to a shared object again, exceeds :func:`expansion_limit`."""
    try:
        root = _simulate(data)
    except Exception as err:  # noqa: BLE001 - ValueError / EOF of every kind: not a well-formed pickle
        raise InputError(source, f"cannot read this pickle as {what} (malformed: {cut_quotes(str(err))})") from None
    if not isinstance(root, _Node):
        return
    sizes = _expanded(root)
    total, depth = sizes[id(root)]
    if depth > MAX_DEPTH:
        field = _top_field(root, sizes, 1)
        where = f" (field '{field}')" if field else ""
        raise InputError(
            source,
            f"refused this pickle as {what}: objects nested {depth} deep{where}, more than the "
            f"{MAX_DEPTH} silfit reads",
            field=field,
        )
    limit = expansion_limit(len(data))
    field = _top_field(root, sizes, 0)
    where = f", most of it field '{field}'" if field else ""
    if total > limit:
        raise InputError(
            source,
            f"refused this pickle as {what}: it would unpack to {total / 1024**2:,.0f} MiB{where} (shared objects "
            f"counted at every reference), more than the {limit / 1024**2:,.0f} MiB silfit allows for a {len(data):,}-byte pickle",
            field=field,
        )


def _unpickle(data: bytes, source: str, what: str) -> Any:
    """Check the opcodes and bound what they build (:func:`_check_bounds`), then unpickle
    with :class:`RestrictedUnpickler`."""
    _check_bounds(data, source, what)
    with io.BytesIO(data) as fh:
        try:
            return RestrictedUnpickler(fh, source, what).load()
        except UnsafeFileError:
            raise
        except RecursionError:
            raise InputError(source, f"cannot read this pickle as {what} (nested too deeply)") from None
        except MemoryError:
            raise InputError(
                source, f"cannot read this pickle as {what} (it asks for more memory than there is)"
            ) from None
        except Exception as err:  # noqa: BLE001 - any other unpickling failure is a bad file
            raise InputError(
                source, f"cannot read this pickle as {what} ({type(err).__name__}: {cut_quotes(str(err))})"
            ) from None


def _npz_member_with_objects(zf: zipfile.ZipFile, key: str, source: str, what: str) -> np.ndarray:
    """An object array of a ``.npz`` (numpy stores it as a pickle after the ``.npy`` header),
    read through :class:`RestrictedUnpickler`."""
    info = zf.getinfo(f"{key}.npy")
    if info.file_size > MAX_FILE_BYTES:
        raise InputError(source, f"field '{key}' unpacks to {info.file_size / 1024**3:.1f} GiB", field=key)
    with zf.open(info) as fh:
        version = np.lib.format.read_magic(fh)
        if version == (1, 0):
            np.lib.format.read_array_header_1_0(fh)
        elif version == (2, 0):
            np.lib.format.read_array_header_2_0(fh)
        else:
            raise InputError(source, f"field '{key}' uses .npy format {version}, which silfit does not read", field=key)
        data = fh.read()
    value = _unpickle(data, f"{source} (field '{key}')", what)
    if not isinstance(value, np.ndarray):
        raise InputError(source, f"field '{key}' holds a pickled {type(value).__name__}, not an array", field=key)
    return value


def load_npz(path: Union[str, os.PathLike], what: str = "silfit input", allow_objects: bool = False) -> dict:
    """All arrays of a ``.npz`` file as a dict. Object arrays (pickles inside the archive)
    are refused unless ``allow_objects``, and then read only through
    :class:`RestrictedUnpickler`. Errors name the file (and the field)."""
    source = os.fspath(path)
    if not os.path.isfile(source):
        raise FileNotFoundError(f"{source}: file not found")
    _check_size(source)
    if not zipfile.is_zipfile(source):
        raise InputError(source, "not a .npz file (not a zip archive of arrays)")
    out = {}
    try:
        with np.load(source, allow_pickle=False) as data, zipfile.ZipFile(source) as zf:
            for key in data.files:
                try:
                    out[key] = data[key]
                except ValueError as err:
                    if "allow_pickle" not in str(err):
                        raise InputError(source, f"field '{key}' is not a readable array ({err})", field=key) from None
                    if not allow_objects:
                        raise InputError(
                            source, f"field '{key}' holds Python objects, not numbers", field=key
                        ) from None
                    out[key] = _npz_member_with_objects(zf, key, source, what)
    except InputError:
        raise
    except MemoryError:
        raise InputError(source, "a field asks for more memory than there is (corrupt header?)") from None
    except Exception as err:  # noqa: BLE001 - zip/npy errors of every kind: not a readable archive
        raise InputError(source, f"not a readable .npz file ({type(err).__name__}: {err})") from None
    return out


def to_numpy(value: Any, _depth: int = 0) -> Any:
    """Stand-ins (chumpy, sparse) to dense arrays; a 0-d object array holding one is
    unwrapped; anything else is returned as it is."""
    if _depth > 8:
        raise ValueError("stand-in objects nested too deeply")
    if isinstance(value, np.ndarray) and value.dtype == object and value.shape == ():
        return to_numpy(value.item(), _depth + 1)
    if isinstance(value, _StandIn):
        return value.to_array(_depth)
    return value
