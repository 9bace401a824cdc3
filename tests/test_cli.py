"""The `ramavt` command line: listing, rendering an episode, clear errors."""

import pytest

from ramavt_jax import cli


def test_targets_lists_catalogue(capsys):
    cli.main(["targets"])
    out = capsys.readouterr().out
    lines = [line for line in out.splitlines()[1:] if line.strip()]
    assert len(lines) == 18
    assert sum(" test " in line for line in lines) == 6
    cli.main(["targets", "--split", "test"])
    assert len(capsys.readouterr().out.strip().splitlines()) == 7


def test_render_writes_gif(tmp_path, capsys):
    out = tmp_path / "episode.gif"
    cli.main(["render", "--target", "Capsule-v0", "--policy", "oracle", "--steps", "6", "--resolution", "16",
              "--size", "64", "--out", str(out)])
    assert out.is_file() and out.stat().st_size > 1000
    import imageio.v2 as imageio

    frames = imageio.mimread(out)
    assert len(frames) == 6 and frames[0].shape[1] == 3 * 64
    assert "6 steps tracked" in capsys.readouterr().out


def test_render_unknown_target_is_a_clear_error(tmp_path, capsys):
    with pytest.raises(SystemExit) as e:
        cli.main(["render", "--target", "Satelite-v1", "--steps", "2", "--out", str(tmp_path / "x.gif")])
    assert e.value.code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "unknown target 'Satelite-v1'" in err and "Did you mean Satellite-v1" in err
    with pytest.raises(ValueError, match="unknown target"):  # --debug: the exception itself, with its traceback
        cli.main(["--debug", "render", "--target", "Enterprise", "--steps", "2", "--out", str(tmp_path / "x.gif")])


def test_bench_scaling_offered_and_splits_envs_over_two_forced_cpu_devices(tmp_path, capsys):
    """`ramavt bench scaling` is a choice; one tiny worker process with 2 forced CPU devices holds the env state
    split over both (2 envs each) and the parent writes JSON and the plot."""
    import importlib.util
    import json
    from pathlib import Path

    with pytest.raises(SystemExit):
        cli.main(["bench", "--help"])
    assert "scaling" in capsys.readouterr().out
    path = Path(cli.__file__).resolve().parents[2] / "benchmarks" / "bench_scaling.py"
    spec = importlib.util.spec_from_file_location("bench_scaling", path)
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    out = tmp_path / "scaling.json"
    result = bench.run(out=out, devices=(2,), envs_per_device=(2,), train_envs_per_device=0, real_devices=False,
                       resolution=16, budget_s=0.05, env_partitions=("shard_map",), timeout_s=150)
    (point,) = result["points"]
    assert point["devices"] == 2 and point["state_devices"] == 2 and point["rows_per_shard"] == [2]
    assert point["env_steps_per_s"] > 0 and point["partition"] == "shard_map"
    assert json.loads(out.read_text())["partial"] is False
    assert (tmp_path / "scaling.png").is_file()
