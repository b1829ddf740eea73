"""The validation split: held out from training, disjoint from the test frames, and visible in
the run's outputs."""
from __future__ import annotations

import numpy as np
import pytest

from scenes.scene import Frame, ModalityData
from smokeseer.config import make_config
from scenes.splits import hold_out_validation


def _rgb(n: int, test_every: int = 8) -> ModalityData:
    frames = [Frame(f"{i:04d}", np.eye(4), np.eye(3), 8, 6, i / 12.0, i / max(n - 1, 1),
                    "test" if i % test_every == test_every // 2 else "train") for i in range(n)]
    return ModalityData("rgb", frames, np.zeros((n, 6, 8, 3), dtype=np.float32))


def test_every_eighth_train_frame_is_validation_and_never_a_test_frame() -> None:
    rgb = _rgb(60)
    test_before = rgb.indices("test")
    held = hold_out_validation(rgb.frames, 8)
    assert held == list(range(0, 60, 8))
    assert rgb.indices("val") == held
    assert rgb.indices("test") == test_before  # the test split is untouched
    assert not set(held) & set(test_before)
    assert len(rgb.indices("train")) == 60 - len(held) - len(test_before)


def test_zero_holds_out_nothing() -> None:
    rgb = _rgb(12)
    assert hold_out_validation(rgb.frames, 0) == []
    assert rgb.indices("val") == []


@pytest.mark.parametrize("every", [-1, 1])
def test_invalid_every_is_refused(every: int) -> None:
    with pytest.raises(ValueError, match="validation_every"):
        hold_out_validation(_rgb(12).frames, every)


def test_too_few_frames_left_is_refused() -> None:
    with pytest.raises(ValueError, match="validation_every: 2 would leave"):
        hold_out_validation(_rgb(3, test_every=3).frames, 2)


def test_profiles_hold_out_validation_except_quick() -> None:
    assert make_config(profile="quick").validation_every == 0
    assert make_config(profile="standard").validation_every == 8
    assert make_config(profile="paper").validation_every == 8
    with pytest.raises(ValueError, match="validation_every"):
        make_config(profile="standard", overrides={"validation_every": 1})


def test_validation_views_are_scored_logged_and_not_trained_on(tmp_path) -> None:
    """A run with a validation split scores it in metrics.json and logs val_psnr; the trainer
    draws no validation frame (the held-out frames keep their split through training)."""
    import csv
    import json

    from smokeseer.api import prepare
    from smokeseer.cli import main
    from tests.test_smokeseer_data import write_splat_dataset
    from tests.test_trainer import TINY

    data = write_splat_dataset(tmp_path / "moving", n_rgb=8, n_thermal=6)
    prep = prepare(data, overrides={"validation_every": 3})
    test = prep.scene.rgb.indices("test")
    assert prep.scene.rgb.indices("val") == [i for i in (0, 3, 6) if i not in test] and test
    assert not set(prep.scene.rgb.indices("val")) & set(prep.scene.rgb.indices("train"))
    run = tmp_path / "run"
    assert main([str(data), "--out", str(run), "--set", "validation_every=3"] + TINY) == 0
    doc = json.loads((run / "metrics.json").read_text())
    assert doc["validation"]["views"] == len(prep.scene.rgb.indices("val")) and np.isfinite(doc["validation"]["psnr"])
    with (run / "train_log.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    assert any(r["val_psnr"] for r in rows) and any(r["test_psnr"] for r in rows)
