import hashlib

import numpy as np
import pytest

from silfit.detect import models


@pytest.mark.parametrize("name", sorted(models.MODEL_FILES))
def test_shipped_model_checksums(name):
    filename, digest = models.MODEL_FILES[name]
    path = models.MODEL_DIR / filename
    assert hashlib.sha256(path.read_bytes()).hexdigest() == digest
    assert models.verify_model(name) == path


def test_licence_notice_shipped_beside_the_models():
    text = (models.MODEL_DIR / "LICENSE-mediapipe.txt").read_text()
    assert "Apache License" in text and "Version 2.0" in text
    readme = (models.MODEL_DIR / "README.md").read_text()
    for filename, digest in models.MODEL_FILES.values():
        assert filename in readme and digest in readme


def test_corrupt_model_is_reported(tmp_path, monkeypatch):
    bad = tmp_path / "pose_detection.tflite"
    bad.write_bytes(b"not a model")
    monkeypatch.setattr(models, "MODEL_DIR", tmp_path)
    with pytest.raises(ValueError, match="corrupt"):
        models.verify_model("pose_detection")
    bad.unlink()
    with pytest.raises(FileNotFoundError, match="missing"):
        models.verify_model("pose_detection")


def test_models_load_with_the_expected_tensors():
    det = models.load_model("pose_detection")
    assert det.input_shape == (1, 224, 224, 3)
    assert sorted(det.output_shapes) == [(1, 2254, 1), (1, 2254, 12)]
    lm = models.load_model("pose_landmark_full")
    assert lm.input_shape == (1, 256, 256, 3)
    assert sorted(lm.output_shapes) == sorted([(1, 195), (1, 1), (1, 256, 256, 1), (1, 64, 64, 39), (1, 117)])
    # A blank crop holds no person.
    flag = [o for o in lm(np.zeros((1, 256, 256, 3), np.float32)) if o.size == 1][0]
    assert float(flag.reshape(())) < 0.5
