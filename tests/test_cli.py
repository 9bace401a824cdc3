"""The `ramavt` command line: listing, rendering an episode, clear errors."""

import pytest

from ramavt_jax import cli


def test_targets_lists_catalogue(capsys):
    cli.main(["targets"])
    out = capsys.readouterr().out
    lines = [line for line in out.splitlines()[1:] if line.strip()]
    assert len(lines) == 24
    assert sum(" test " in line for line in lines) == 6 and sum(" val " in line for line in lines) == 6
    cli.main(["targets", "--split", "test"])
    assert len(capsys.readouterr().out.strip().splitlines()) == 7
    cli.main(["targets", "--split", "val"])
    val_lines = capsys.readouterr().out.strip().splitlines()[1:]
    assert len(val_lines) == 6 and all(" val " in line and "-val" in line for line in val_lines)


def test_render_writes_gif(tmp_path, capsys):
    out = tmp_path / "episode.gif"
    cli.main(
        [
            "render",
            "--target",
            "Capsule-v0",
            "--policy",
            "proportional",
            "--steps",
            "6",
            "--resolution",
            "16",
            "--size",
            "64",
            "--out",
            str(out),
        ]
    )
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


@pytest.mark.slow  # a benchmark run in a subprocess on two forced devices (about 40 s idle)
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
    result = bench.run(
        out=out,
        devices=(2,),
        envs_per_device=(2,),
        train_envs_per_device=0,
        real_devices=False,
        resolution=16,
        budget_s=0.05,
        env_partitions=("shard_map",),
        timeout_s=150,
    )
    (point,) = result["points"]
    assert point["devices"] == 2 and point["state_devices"] == 2 and point["rows_per_shard"] == [2]
    assert point["env_steps_per_s"] > 0 and point["partition"] == "shard_map"
    assert json.loads(out.read_text())["partial"] is False
    assert (tmp_path / "scaling.png").is_file()


# ============================================================================================ bad inputs
MESH_XML = """<mujoco><asset><mesh name="m" vertex="0 0 0 1 0 0 0 1 0 0 0 1"/></asset>
<worldbody><body><geom type="mesh" mesh="m"/></body></worldbody></mujoco>"""
PLANE_XML = '<mujoco><worldbody><body><geom type="plane" size="1 1 0.1"/></body></worldbody></mujoco>'
EMPTY_XML = "<mujoco><worldbody/></mujoco>"
TRUNCATED_XML = '<mujoco><worldbody><body><geom type="sphere" size="1"'


def _files(tmp_path):
    for name, text in (
        ("mesh.xml", MESH_XML),
        ("plane.xml", PLANE_XML),
        ("empty.xml", EMPTY_XML),
        ("truncated.xml", TRUNCATED_XML),
    ):
        (tmp_path / name).write_text(text)
    (tmp_path / "a_file").write_text("x")
    (tmp_path / "a_folder").mkdir()
    return tmp_path


TRAIN = ["train", "--preset", "smoke", "--no-progress"]
BAD_INPUTS = {  # id: (arguments, {tmp} filled in, what the one-line message must say)
    "unknown target": (["render", "--target", "Satelite-v1"], "Did you mean Satellite-v1"),
    "target is a folder": (["render", "--target", "{tmp}/a_folder"], "is a folder"),
    "truncated MJCF": (["render", "--target", "{tmp}/truncated.xml"], "cannot parse MJCF"),
    "mesh geom": (["render", "--target", "{tmp}/mesh.xml"], "mesh"),
    "plane geom": (["render", "--target", "{tmp}/plane.xml"], "plane"),
    "empty model": (["render", "--target", "{tmp}/empty.xml"], "no geoms"),
    "render steps negative": (["render", "--steps", "-5"], "--steps must be an integer >= 1"),
    "render steps zero": (["render", "--steps", "0"], "--steps must be an integer >= 1"),
    "render out is a folder": (["render", "--steps", "2", "--out", "{tmp}/a_folder"], "must end in .gif or .mp4"),
    "render out under a file": (["render", "--steps", "2", "--out", "{tmp}/a_file/x.gif"], "is a file"),
    "total steps negative": (TRAIN + ["--run.total-env-steps", "-320"], "total_env_steps must be >= 1"),
    "total steps not a multiple": (TRAIN + ["--run.total-env-steps", "1000"], "must be a multiple"),
    "bad learning rate": (TRAIN + ["--learner.lr", "-1"], "lr must be > 0"),
    "seeds zero": (TRAIN + ["--seeds", "0"], "--seeds must be an integer >= 1"),
    "more devices than visible": (TRAIN + ["--devices", "3", "--out", "{tmp}/three"], "device(s) are visible"),
    "train out is a file": (TRAIN + ["--out", "{tmp}/a_file"], "is a file, not a folder"),
    "unknown preset": (["train", "--preset", "fast"], "unknown preset 'fast'"),
    "eval episodes zero": (["eval", "--policy", "random", "--episodes", "0"], "--episodes must be an integer >= 1"),
    "eval run missing": (["eval", "--run", "{tmp}/no_run"], "config.json not found"),
    "eval speed power": (
        ["eval", "--policy", "random", "--speed-standoff-power", "2"],
        "--speed-standoff-power must be in [0, 1]",
    ),
    "eval out is a file": (["eval", "--policy", "random", "--out", "{tmp}/a_file"], "is a file"),
    "plot run missing": (["plot", "--run", "{tmp}/no_run", "--out", "{tmp}/fig"], "config.json not found"),
}


@pytest.mark.parametrize("name", list(BAD_INPUTS))
def test_bad_input_is_one_line_and_exit_code_2(name, tmp_path, capsys):
    args, expected = BAD_INPUTS[name]
    tmp = _files(tmp_path)
    args = [a.replace("{tmp}", str(tmp)) for a in args]
    if args[0] == "render" and "--out" not in args:
        args += ["--out", str(tmp / "x.gif")]
    with pytest.raises(SystemExit) as e:
        cli.main(args)
    assert e.value.code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    assert err.startswith("ramavt: error: ") and expected in err, err
    assert not (tmp / "three").exists()  # a bad device count leaves no run folder behind


def test_read_only_out_is_one_line(tmp_path, capsys):
    import os

    if os.geteuid() == 0:
        pytest.skip("root can write into read-only folders")
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    with pytest.raises(SystemExit) as e:
        cli.main(TRAIN + ["--out", str(ro / "run")])
    assert e.value.code == 2 and "ro" in capsys.readouterr().err


# ============================================================================================ train flags
def test_every_training_field_is_a_flag_and_preset_picks_the_defaults(monkeypatch):
    """Grouped flags set every config group's fields, and --preset picks the defaults they change."""
    from ramavt_jax.cli import train as cli_train
    from ramavt_jax.presets import preset

    seen = {}

    def fake(config, out, **kwargs):
        seen.update(config=config, out=out, **kwargs)
        raise SystemExit(0)

    monkeypatch.setattr(cli_train, "train_and_evaluate", fake)
    with pytest.raises(SystemExit):
        cli.main(
            [
                "train",
                "--preset",
                "smoke",
                "--learner.lr",
                "3e-4",
                "--network.lstm",
                "48",
                "--env.camera.resolution",
                "24",
                "--learner.gamma",
                "0.9",
                "--network.variant",
                "drlavt",
                "--env.obs-mode",
                "rgbd",
                "--learner.augment",
                "--learner.augment-config.crop",
                "--learner.no-double-q",
                "--run.total-env-steps",
                "2560",
                "--env-params",
                "dist_weight=0.5",
                "lost_patience=10",
                "--replay.capacity-steps=1600",
                "--out",
                "somewhere",
            ]
        )
    cfg = seen["config"]
    smoke = preset("smoke")
    assert (cfg.learner.lr, cfg.network.lstm, cfg.env.camera.resolution, cfg.learner.gamma) == (3e-4, 48, 24, 0.9)
    assert (cfg.network.variant, cfg.env.obs_mode, cfg.learner.augment, cfg.learner.double_q) == (
        "drlavt",
        "rgbd",
        True,
        False,
    )
    assert cfg.learner.augment_config.crop and not smoke.learner.augment_config.crop
    assert cfg.run.total_env_steps == 2560 and cfg.replay.capacity_steps == 1600 and str(seen["out"]) == "somewhere"
    assert dict(cfg.env_params) == {"dist_weight": 0.5, "lost_patience": 10}
    assert cfg.replay.batch_size == smoke.replay.batch_size and cfg.network.dense == smoke.network.dense  # preset's


def test_train_help_groups_every_config_field(capsys):
    """`ramavt train --help` has one section per config group, with every field of it a flag."""
    import dataclasses

    from ramavt_jax.train_config import TrainConfig

    with pytest.raises(SystemExit):
        cli.main(["train", "--preset", "smoke", "--help"])
    text = capsys.readouterr().out
    for group in ("env", "env.camera", "network", "acting", "replay", "learner", "learner.augment-config", "run"):
        assert f"{group} options" in text, group

    def flags(prefix, config):
        for f in dataclasses.fields(config):
            value = getattr(config, f.name)
            if dataclasses.is_dataclass(value):
                yield from flags(f"{prefix}{f.name.replace('_', '-')}.", value)
            else:
                yield f"--{prefix}{f.name.replace('_', '-')}"

    for flag in flags("", TrainConfig()):
        assert flag in text, flag
    assert "debug-nan" not in text  # the trainer's test hook is not a flag


@pytest.mark.slow
def test_sigterm_to_ramavt_train_exits_143_and_the_rerun_resumes(tmp_path):
    """A real `ramavt train` process gets SIGTERM after its first metrics row: it saves, exits with 143, keeps
    every row it logged, and the same command resumes from the saved chunk to the end."""
    import json
    import signal
    import subprocess
    import sys
    import time

    out = tmp_path / "run"
    cmd = [
        sys.executable,
        "-m",
        "ramavt_jax.cli",
        "train",
        "--preset",
        "smoke",
        "--out",
        str(out),
        "--no-progress",
        "--run.eval-episodes",
        "0",
        "--run.checkpoint-every-chunks",
        "0",
    ]
    env = {**__import__("os").environ, "RAMAVT_COMPILE_CACHE": str(tmp_path / "cache")}
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    metrics = out / "metrics.jsonl"
    deadline = time.time() + 600
    while not (metrics.exists() and metrics.read_text().strip()) and time.time() < deadline:
        time.sleep(0.05)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=300)
    assert proc.returncode == 143, err
    assert err.strip().splitlines()[-1].startswith("ramavt: SIGTERM")
    rows = [json.loads(line)["chunk"] for line in metrics.read_text().splitlines()]
    saved = max(int(p.name) for p in (out / "checkpoints").iterdir())
    assert rows == list(range(1, saved + 1))  # the chunk in flight was logged and checkpointed
    again = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=900)
    assert again.returncode == 0, again.stderr[-2000:]
    assert [json.loads(line)["chunk"] for line in metrics.read_text().splitlines()] == [1, 2, 3, 4]


# ------------------------------------------------------------------------------------------ huge-page launcher
def test_launcher_adds_the_huge_page_tunable_once_and_respects_opt_out():
    from ramavt_jax.launch import TUNABLE, huge_page_environment

    assert huge_page_environment({"A": "1"}, "linux")["GLIBC_TUNABLES"] == TUNABLE
    kept = huge_page_environment({"GLIBC_TUNABLES": "glibc.malloc.arena_max=2"}, "linux")["GLIBC_TUNABLES"]
    assert kept == f"glibc.malloc.arena_max=2:{TUNABLE}"
    assert huge_page_environment({"GLIBC_TUNABLES": TUNABLE}, "linux") is None  # the re-executed process: no loop
    assert huge_page_environment({"RAMAVT_HUGEPAGES": "0"}, "linux") is None
    assert huge_page_environment({}, "darwin") is None


def test_console_re_executes_with_the_tunable_and_runs_the_cli_when_it_cannot(monkeypatch):
    import sys

    import ramavt_jax.cli as cli
    from ramavt_jax import launch

    calls, ran = [], []

    def fake_execve(exe, args, env):
        calls.append((exe, args, env))
        raise OSError("no exec here")

    monkeypatch.setattr(launch.os, "execve", fake_execve)
    monkeypatch.setattr(cli, "main", lambda: ran.append(True))
    monkeypatch.delenv("GLIBC_TUNABLES", raising=False)
    monkeypatch.delenv("RAMAVT_HUGEPAGES", raising=False)
    monkeypatch.setattr(sys, "argv", ["ramavt", "targets", "list"])
    launch.console()
    if sys.platform.startswith("linux"):
        ((exe, args, env),) = calls
        assert exe == sys.executable and args == [sys.executable, "ramavt", "targets", "list"]
        assert env["GLIBC_TUNABLES"] == launch.TUNABLE
    assert ran == [True]
    calls.clear()
    monkeypatch.setenv("GLIBC_TUNABLES", launch.TUNABLE)
    launch.console()
    assert calls == [] and ran == [True, True]


@pytest.mark.parametrize("which", ["online", "target", "averaged"])
def test_final_evaluation_acts_with_the_configured_params(tmp_path, monkeypatch, which):
    """`ramavt train`'s end-of-run evaluation gets the parameter set run.policy_params names."""
    from types import SimpleNamespace

    import numpy as np

    from ramavt_jax import experiment
    from ramavt_jax.presets import preset
    from ramavt_jax.train_state import LearnerState
    from ramavt_jax.training import driver

    def fake_run(config, out, **kwargs):
        summary = driver.RunSummary(seed=0, out_dir=str(out), last=None, finished=True)
        summary.state = SimpleNamespace(
            learner=LearnerState(
                params={"w": np.ones(2)},
                target_params={"w": np.full(2, 7.0)},
                opt_state=None,
                updates=0,
                averaged_params={"w": np.full(2, 3.0)},
            )
        )
        return summary

    seen = {}
    monkeypatch.setattr(experiment.driver, "run", fake_run)
    monkeypatch.setattr(experiment, "evaluate_run", lambda config, d, seed, params, log: seen.update(params=params))
    experiment.train_and_evaluate(
        preset("smoke", policy_params=which, policy_average_from=2), tmp_path, seed=0, progress=False
    )
    expected = {"online": 1.0, "target": 7.0, "averaged": 3.0}[which]
    np.testing.assert_array_equal(seen["params"]["w"], np.full(2, expected))


def test_env_params_add_to_a_presets_pairs(monkeypatch):
    """Under a preset that sets EnvParams pairs (`sizes`), --env-params parses as under any other and adds to them
    name by name."""
    from ramavt_jax.cli import train as cli_train

    seen = {}
    monkeypatch.setattr(cli_train, "train_and_evaluate", lambda config, out, **kw: seen.update(config=config))
    monkeypatch.setattr(cli_train, "_print_summary", lambda *a: None)
    cli.main(["train", "--preset", "sizes", "--env-params", "stretch_max=1.5", "size_scale_max=0.8", "--out", "x"])
    assert dict(seen["config"].env_params) == {
        "size_scale_min": 0.15,
        "size_scale_max": 0.8,
        "stretch_max": 1.5,
        "init_xy_std": 3.0,
    }
    cli.main(["train", "--preset", "sizes", "--out", "x"])
    assert dict(seen["config"].env_params) == {"size_scale_min": 0.15, "size_scale_max": 1.0, "init_xy_std": 3.0}


def test_repeated_env_params_add_up_and_a_default_undoes_a_presets_pair(monkeypatch):
    """--env-params given twice adds up (a later pair of a name wins) instead of the last one replacing the first;
    a pair at EnvParams' default removes the preset's pair of that name, so the config is the preset's without it."""
    from ramavt_jax.cli import train as cli_train
    from ramavt_jax.presets import preset

    seen = {}
    monkeypatch.setattr(cli_train, "train_and_evaluate", lambda config, out, **kw: seen.update(config=config))
    monkeypatch.setattr(cli_train, "_print_summary", lambda *a: None)
    cli.main(
        [
            "train",
            "--preset",
            "sizes",
            "--env-params",
            "init_xy_std=1",
            "stretch_max=2",
            "--seeds",
            "1",
            "--env-params=stretch_max=1.5",
            "--env-params",
            "dist_weight=0.5",
            "--out",
            "x",
        ]
    )
    assert dict(seen["config"].env_params) == {
        "size_scale_min": 0.15,
        "size_scale_max": 1.0,
        "stretch_max": 1.5,
        "dist_weight": 0.5,
    }
    cli.main(["train", "--preset", "sizes", "--env-params", "init_xy_std=1", "--out", "x"])
    assert seen["config"] == preset("sizes").override(env_params={"size_scale_min": 0.15, "size_scale_max": 1.0})
    assert cli_train.joined_env_params(["train", "--seeds", "2"]) == ["train", "--seeds", "2"]


def test_train_without_a_preset_trains_the_general_preset_into_runs_general(monkeypatch):
    from pathlib import Path

    from ramavt_jax.cli import train as cli_train
    from ramavt_jax.presets import preset

    seen = {}
    monkeypatch.setattr(cli_train, "train_and_evaluate", lambda config, out, **kw: seen.update(config=config, out=out))
    monkeypatch.setattr(cli_train, "_print_summary", lambda *a: None)
    cli.main(["train"])
    assert seen["config"] == preset("general") and Path(seen["out"]) == Path("runs/general")
