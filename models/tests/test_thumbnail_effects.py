"""The offline look at camera effects: what each effect does to a thumbnail, and that it
never reads the seeds kept for choosing and reporting."""

import numpy as np
import pytest

from dribble_models.thumbnail_effects import SEVERITY_3, ThumbnailEffect, main

from test_train import write_dataset


def test_each_effect_changes_a_thumbnail_as_its_condition_does():
    rng = np.random.default_rng(0)
    frames = rng.integers(40, 216, (4, 120, 160), dtype=np.uint8)
    same = lambda effect: effect.apply(frames, np.random.default_rng(1))  # noqa: E731
    assert np.array_equal(same(ThumbnailEffect("clean")), frames)
    halved = same(ThumbnailEffect("c", contrast=0.5)).astype(float)
    assert abs((halved - 127.5).std() / (frames - 127.5).std() - 0.5) < 0.01
    assert same(ThumbnailEffect("dark", exposure_ev=-0.7)).mean() < frames.mean() < same(ThumbnailEffect("bright", exposure_ev=0.7)).mean()
    noisy = same(ThumbnailEffect("n", noise=5 / 255)).astype(float) - frames
    assert 4.0 < noisy.std() < 6.0 and abs(noisy.mean()) < 0.2
    blurred = same(ThumbnailEffect("b", blur=True)).astype(float)
    assert blurred.std() < frames.std() / 2
    turned = same(ThumbnailEffect("t", smear_px=4.0)).astype(float)
    # A turn smears along the rows: neighbours in a row share most of what they average,
    # neighbours in a column none of it.
    assert np.abs(np.diff(turned, axis=2)).mean() < np.abs(np.diff(turned, axis=1)).mean() / 2
    # The same seed, the same noise.
    assert np.array_equal(same(ThumbnailEffect("n", noise=0.02)), same(ThumbnailEffect("n", noise=0.02)))
    assert [e.name for e in SEVERITY_3][0] == "clean"


@pytest.mark.parametrize("seed", [10000, 20010, 30099])
def test_the_seeds_kept_for_choosing_and_reporting_are_refused(tmp_path, seed, capsys):
    data = write_dataset(tmp_path / "d", [1, seed], 2, np.random.default_rng(0))
    assert main(["--dataset", str(data), "--seeds", f"1,{seed}", str(tmp_path / "model")]) == 2
    assert "kept for choosing and reporting" in capsys.readouterr().err


def test_a_directory_that_is_no_shipped_cnn_is_named(tmp_path, capsys):
    data = write_dataset(tmp_path / "d", [1], 2, np.random.default_rng(0))
    (tmp_path / "model").mkdir()
    assert main(["--dataset", str(data), "--seeds", "1", str(tmp_path / "model")]) == 2
    assert "thumbnail_effects:" in capsys.readouterr().err
