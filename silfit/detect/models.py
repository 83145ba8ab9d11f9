"""The shipped BlazePose GHUM model files and the LiteRT interpreters that run them.

The ``.tflite`` files come unchanged from the ``mediapipe==0.10.21`` wheel (Apache-2.0,
see ``data/README.md``); they run on the CPU through ``ai-edge-litert``, so nothing is
downloaded at run time and mediapipe itself is not needed.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import sys
from functools import lru_cache
from pathlib import Path

import numpy as np

__all__ = ["MODEL_DIR", "MODEL_FILES", "model_path", "verify_model", "TfliteModel", "load_model"]

MODEL_DIR = Path(__file__).resolve().parent / "data"

#: Model name -> (file name, sha256) of the shipped files.
MODEL_FILES = {
    "pose_detection": ("pose_detection.tflite", "9ba9dd3d42efaaba86b4ff0122b06f29c4122e756b329d89dca1e297fd8f866c"),
    "pose_landmark_full": (
        "pose_landmark_full.tflite",
        "e9a5c5cb17f736fafd4c2ec1da3b3d331d6edbe8a0d32395855aeb2cdfd64b9f",
    ),
}


def model_path(name: str) -> Path:
    try:
        filename, _ = MODEL_FILES[name]
    except KeyError:
        raise ValueError(f"unknown detection model {name!r} (expected one of {', '.join(MODEL_FILES)})") from None
    return MODEL_DIR / filename


def verify_model(name: str) -> Path:
    """The model's path, after checking that the file exists and has the shipped checksum."""
    path = model_path(name)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: detection model file missing (reinstall silfit)")
    digest = hashlib.sha256(path.read_bytes()).hexdigest()
    if digest != MODEL_FILES[name][1]:
        raise ValueError(
            f"{path}: detection model file is corrupt (sha256 {digest[:12]}..., expected {MODEL_FILES[name][1][:12]}...)"
        )
    return path


@contextlib.contextmanager
def _quiet_stderr():
    """Silence the native 'Created TensorFlow Lite XNNPACK delegate' line LiteRT prints."""
    try:
        fd = sys.stderr.fileno()
    except (AttributeError, OSError, ValueError):
        yield
        return
    sys.stderr.flush()
    saved = os.dup(fd)
    try:
        with open(os.devnull, "w") as null:
            os.dup2(null.fileno(), fd)
            yield
    finally:
        os.dup2(saved, fd)
        os.close(saved)


class TfliteModel:
    """One LiteRT interpreter: ``model(x)`` runs it on a float32 input and returns the
    output tensors (copies) in the model's output order."""

    def __init__(self, path: os.PathLike, num_threads: int = 2):
        from ai_edge_litert.interpreter import Interpreter

        with _quiet_stderr():
            self._interp = Interpreter(model_path=os.fspath(path), num_threads=int(num_threads))
            self._interp.allocate_tensors()
        (self._input,) = self._interp.get_input_details()
        self._outputs = self._interp.get_output_details()
        self.input_shape = tuple(int(v) for v in self._input["shape"])
        self.output_shapes = [tuple(int(v) for v in o["shape"]) for o in self._outputs]

    def __call__(self, x: np.ndarray) -> list:
        x = np.ascontiguousarray(x, dtype=np.float32).reshape(self.input_shape)
        self._interp.set_tensor(self._input["index"], x)
        self._interp.invoke()
        return [np.array(self._interp.get_tensor(o["index"])) for o in self._outputs]


@lru_cache(maxsize=None)
def load_model(name: str, num_threads: int = 2) -> TfliteModel:
    """The (cached) interpreter of a shipped model, checksum verified on first use."""
    return TfliteModel(verify_model(name), num_threads=num_threads)
