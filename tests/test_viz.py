"""Figures: attention maps (each sums to 1) overlaid on the input, frame strips, seed bands of training curves,
and `ramavt plot` end to end with a baseline."""

import json

import jax
import numpy as np
import pytest

from ramavt_jax import network
from ramavt_jax.cli import evaluate as cli_eval
from ramavt_jax.figures import episode, training


def test_attention_maps_sum_to_one_and_plot(tmp_path):
    cfg = network.NetworkConfig(
        variant="ramavt",
        channels=(8, 8, 8),
        kernels=(3, 3, 1),
        strides=(1, 1, 1),
        pools=(True, True, True),
        se_reduction=2,
        attention_heads=2,
        dense=16,
        lstm=16,
        lstm_layers=1,
        head=16,
    )
    params = network.init_params(cfg, jax.random.PRNGKey(0), (16, 16, 1))["params"]
    obs = np.zeros((2, 16, 16, 1), np.float32)
    obs[0, 4:9, 5:11] = 0.3
    obs[1, 8:14, 2:6] = 0.6
    maps = episode.attention_panels(params, cfg, obs)
    assert len(maps) == 2 and list(maps[0]) == ["block1", "block2", "block3", "mha"]
    for m in maps:
        for name, a in m.items():
            assert np.asarray(a).sum() == pytest.approx(1.0, abs=1e-5), name
            assert np.all(np.asarray(a) >= 0)
    assert maps[0]["block1"].shape == (8, 8)
    path = episode.plot_attention(obs, maps, tmp_path / "att.png")
    assert path.exists() and path.stat().st_size > 1000


def test_frame_strip_indices():
    np.testing.assert_array_equal(episode.strip_indices(1000, 8), np.round(np.linspace(0, 999, 8)).astype(int))
    np.testing.assert_array_equal(episode.strip_indices(3, 8), [0, 1, 2])
    with pytest.raises(ValueError):
        episode.strip_indices(0, 8)


def _write_run(path, xs, ys, variant="ramavt"):
    path.mkdir(parents=True)
    (path / "config.json").write_text(
        json.dumps({"seed": 0, "config": {"network": {"variant": variant}, "env": {"obs_mode": "depth"}}})
    )
    lines = [
        json.dumps(
            {"chunk": i + 1, "env_steps": x, "episode_length": y, "episode_return": -y, "loss": 1.0, "q_mean": 0.5}
        )
        for i, (x, y) in enumerate(zip(xs, ys))
    ]
    (path / "metrics.jsonl").write_text("\n".join(lines) + "\n")


def test_training_bands_mean_std(tmp_path):
    _write_run(tmp_path / "ramavt_s0", [100, 200, 300], [10.0, 20.0, 30.0])
    _write_run(tmp_path / "ramavt_s1", [100, 200, 300], [30.0, 40.0, float("nan")])
    _write_run(tmp_path / "origin-seed0", [100, 200], [5.0, 6.0], variant="origin")
    assert training.group_name(tmp_path / "ramavt_s1") == "ramavt"
    assert training.group_name(tmp_path / "origin-seed0") == "origin"
    assert training.group_name(tmp_path / "sweep" / "seed_3") == "sweep"  # folders of `ramavt train --seeds N`
    runs = [training.read_run(tmp_path / f"ramavt_s{i}") for i in range(2)]
    x, mean, std = training.band([(rx, m["episode_length"]) for rx, m in runs])
    np.testing.assert_array_equal(x, [100, 200, 300])
    # the NaN of seed 1 at 300 is interpolated from its finite points (held at 40)
    np.testing.assert_allclose(mean, [20.0, 30.0, 35.0])
    np.testing.assert_allclose(std, [10.0, 10.0, 5.0])
    out = training.plot_training_runs(
        [tmp_path / "ramavt_s0", tmp_path / "ramavt_s1", tmp_path / "origin-seed0"], tmp_path / "curves.png"
    )
    assert out.exists() and out.stat().st_size > 1000
    assert training.run_label(tmp_path / "origin-seed0") == "origin depth"
    with pytest.raises(FileNotFoundError, match="no training metrics"):
        training.read_run(tmp_path / "missing")


def test_a_run_figure_keeps_the_title_it_is_given(tmp_path, monkeypatch):
    """The figure's title is the caller's, not the last panel's ('epsilon')."""
    import matplotlib.figure

    _write_run(tmp_path / "ramavt_s0", [100, 200], [10.0, 20.0])
    titles = []
    real = matplotlib.figure.Figure.suptitle
    monkeypatch.setattr(
        matplotlib.figure.Figure, "suptitle", lambda fig, text, **kw: titles.append(text) or real(fig, text, **kw)
    )
    training.plot_run(tmp_path / "ramavt_s0", title="ramavt seed 0")
    assert titles == ["ramavt seed 0"]


def test_plot_cmd_baseline(tmp_path):
    _write_run(tmp_path / "runs" / "a_s0", [1, 2], [3.0, 4.0])
    paths = cli_eval.plot_cmd(
        runs=(tmp_path / "runs" / "a_s0",),
        policy="proportional",
        target="Satellite-v2",
        steps=12,
        resolution=16,
        frames=4,
        out=tmp_path / "fig",
    )
    assert set(paths) == {"training_curves", "tracking_error", "trajectory_3d", "frames"}
    for p in paths.values():
        assert (tmp_path / "fig").joinpath(p.split("/")[-1]).stat().st_size > 1000
