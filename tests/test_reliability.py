"""Fault injection, one test per failure a user met: a plan larger than the memory, a torn metrics line, a damaged
newest checkpoint read by `ramavt eval`, an incomplete config.json, more evaluation episodes than fit side by side,
values that are not finite numbers, two commands writing one --out, a signal while compiling. Each ends in exit
status 2 with at most three lines on stderr, or in success where the run can go on; nothing of the run is lost."""

import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from ramavt_jax import cli
from ramavt_jax.presets import preset
from ramavt_jax.train import Trainer
from ramavt_jax.train_config import TrainConfig
from ramavt_jax.training import files, memory, run_folder
from ramavt_jax.training.checkpoint import CheckpointError, CheckpointStore

SMOKE = preset("smoke", eval_episodes=0)
TRAIN = ["train", "--preset", "smoke", "--no-progress"]


def _refused(args, capsys) -> str:
    """Run the CLI in-process; it must exit with 2 and at most three lines on stderr, no traceback."""
    with pytest.raises(SystemExit) as e:
        cli.main(args)
    err = capsys.readouterr().err.strip()
    assert e.value.code == 2, err
    assert 1 <= len(err.splitlines()) <= 3 and "Traceback" not in err, err
    return err


# ============================================================================================ 1. memory
@pytest.mark.parametrize("capacity", ["800000000", "1000000000000"])
def test_a_replay_larger_than_the_memory_is_refused_before_compiling(capacity, tmp_path, capsys):
    err = _refused(TRAIN + ["--replay.capacity-steps", capacity, "--out", str(tmp_path / "run")], capsys)
    assert "needs" in err and ("GiB" in err or "TiB" in err)
    assert "--replay.capacity-steps" in err and "available" in err
    assert not (tmp_path / "run" / "config.json").exists()


def test_available_memory_honours_the_cap(monkeypatch):
    monkeypatch.setenv("RAMAVT_MEMORY_GB", "0.5")
    assert memory.available_bytes() <= 2**29
    with pytest.raises(memory.MemoryPlanError, match="needs 1.0 GiB.*lower it"):
        memory.check_fits(2**30, "a plan", "lower it")
    monkeypatch.setenv("RAMAVT_MEMORY_GB", "nan")
    with pytest.raises(memory.MemoryPlanError, match="RAMAVT_MEMORY_GB"):
        memory.available_bytes()


def test_a_container_limit_caps_the_memory_counted_on(tmp_path):
    """A cgroup's limit minus its usage, not the host's RAM (v2 'max' and v1's huge number mean no limit)."""
    v2, v1 = tmp_path / "memory.max", tmp_path / "memory.limit_in_bytes"
    v2.write_text("1073741824\n")
    (tmp_path / "memory.current").write_text(str(2**28))
    assert memory._cgroup_available((str(v2),)) == 2**30 - 2**28
    v2.write_text("max\n")
    assert memory._cgroup_available((str(v2),)) is None
    v1.write_text(str(2**63 - 4096))
    assert memory._cgroup_available((str(tmp_path / "missing"), str(v1))) is None


def test_the_chunks_working_memory_counts_in_the_training_plan(monkeypatch):
    """A state that fits alone is refused once the compiled chunk's working memory is added to it."""
    from ramavt_jax.training import program

    abstract = jax.eval_shape(Trainer(SMOKE).init, jax.ShapeDtypeStruct((2,), np.uint32))
    state = memory.tree_bytes(abstract)
    monkeypatch.setattr(memory, "available_bytes", lambda device=None: int(2 * state / memory.FRACTION))
    program.check_state_fits(SMOKE, abstract, 1, None)  # the state alone fits
    with pytest.raises(memory.MemoryPlanError, match="working memory"):
        program.check_state_fits(SMOKE, abstract, 1, None, chunk_temp=2 * state)


# ============================================================================================ 2. torn metrics
def test_a_torn_last_metrics_line_is_skipped_in_one_line(tmp_path):
    path = tmp_path / "metrics.jsonl"
    whole = [{"chunk": 1, "loss": 0.5}, {"chunk": 2, "loss": None}]
    text = "".join(files.dumps(r) + "\n" for r in whole)
    path.write_text(text + files.dumps({"chunk": 3, "loss": 0.25})[:9])  # a crash mid-write
    said = []
    records = run_folder.read_metrics(path, log=said.append)
    assert [r["chunk"] for r in records] == [1, 2] and np.isnan(records[1]["loss"])
    assert len(said) == 1 and str(path) in said[0] and "\n" not in said[0]
    path.write_text(text.replace('"loss": 0.5', '"loss": 0.5,,') + files.dumps({"chunk": 3}) + "\n")
    with pytest.raises(run_folder.RunFolderError, match=r"metrics.jsonl line 1 is not a JSON record"):
        run_folder.read_metrics(path, log=said.append)  # damage before the last line is not a crash mid-write


# ============================================================================================ 3. eval fallback
def _fake_run_folder(folder: Path, steps=(2, 4)) -> dict:
    """A run folder with checkpoints of SMOKE's state shape, every leaf of step s filled with s (no training)."""
    like = jax.eval_shape(Trainer(SMOKE).init, jax.ShapeDtypeStruct((2,), jnp.uint32))
    folder.mkdir(parents=True)
    config_json = json.loads(json.dumps(SMOKE.to_dict()))
    (folder / run_folder.CONFIG_FILE).write_text(json.dumps({"seed": 0, "config": config_json}))
    store = CheckpointStore(folder / run_folder.CHECKPOINTS, keep=len(steps))
    for s in steps:
        store.save(s, jax.tree.map(lambda x: np.full(x.shape, s, x.dtype), like), {"config": config_json, "chunk": s})
    store.close()
    return config_json


def _damage(step_dir: Path) -> None:
    for p in (step_dir / "state").rglob("*"):
        if p.is_file() and p.parent.name == "d":
            p.write_bytes(p.read_bytes()[: p.stat().st_size // 2])


def test_eval_falls_back_past_a_damaged_newest_checkpoint_quietly(tmp_path, capfd, monkeypatch):
    import gc

    from ramavt_jax.evaluation.runs import load_policy

    # Earlier tests in this worker may leave abandoned reads of their own; collect them before listening, so that
    # what is reported below comes from this test's reads (an unflushed one failed the suite once, alone it passes).
    time.sleep(0.5)
    gc.collect()
    reported = []  # what Python would print as tracebacks (pytest's own hook turns them into warnings)
    monkeypatch.setattr(sys, "unraisablehook", lambda u: reported.append(str(u.exc_value)))
    _fake_run_folder(tmp_path / "run")
    _damage(tmp_path / "run" / "checkpoints" / "4")
    said = []
    loaded = load_policy(tmp_path / "run", log=said.append)
    assert loaded.step == 2 and all((np.asarray(x) == 2).all() for x in jax.tree.leaves(loaded.params))
    assert len(said) == 1 and "step 4" in said[0] and "using step 2" in said[0] and "\n" not in said[0]
    assert (tmp_path / "run" / "checkpoints" / "4").is_dir()  # a reader deletes nothing
    _damage(tmp_path / "run" / "checkpoints" / "2")
    with pytest.raises(CheckpointError, match="no checkpoint in .* loads") as e:
        load_policy(tmp_path / "run", log=said.append)
    assert len(str(e.value).splitlines()) == 1
    time.sleep(0.5)  # reads still in flight report into the closed event loop
    gc.collect()
    err = capfd.readouterr().err
    assert "Traceback" not in err and "Event loop is closed" not in err, err[:2000]
    assert reported == [], reported[:3]


# ============================================================================================ 4. incomplete config
def _without(config_json: dict, group: str, field: str) -> dict:
    return dict(config_json, **{group: {k: v for k, v in config_json[group].items() if k != field}})


def test_an_incomplete_config_json_is_refused_naming_the_field(tmp_path, capsys):
    config_json = json.loads(json.dumps(SMOKE.to_dict()))
    run = tmp_path / "run"
    (run / "checkpoints" / "2").mkdir(parents=True)  # resume is attempted: a step folder is there
    (run / "config.json").write_text(json.dumps({"seed": 0, "config": _without(config_json, "network", "lstm")}))
    before = (run / "config.json").read_bytes()
    for args in (
        ["eval", "--run", str(run), "--no-baselines", "--out", str(tmp_path / "eval")],
        TRAIN + ["--out", str(run)],
    ):
        err = _refused(args, capsys)
        assert "lacks network.lstm" in err and "config.json" in err, err
    assert (run / "config.json").read_bytes() == before
    (run / "config.json").write_text('{"seed": 0, "config": {"env": ')  # cut short
    assert "cannot read" in _refused(TRAIN + ["--out", str(run)], capsys)


def test_a_config_json_written_before_a_field_was_added_reads_as_that_field_s_old_value(tmp_path):
    """run_folder.ADDED_FIELDS: a config.json without a field added later reads as the value its run was trained
    with; without any other field it is still refused."""
    from ramavt_jax.training import run_folder

    config_json = json.loads(json.dumps(SMOKE.to_dict()))
    older = _without(_without(config_json, "learner", "bootstrap_from"), "learner", "blind_label")
    (tmp_path / "config.json").write_text(json.dumps({"seed": 0, "config": older}))
    learner = run_folder.read_config(tmp_path)["config"]["learner"]
    assert (learner["bootstrap_from"], learner["blind_label"]) == ("target", "teacher")
    no_average = _without(config_json, "run", "policy_average_from")
    (tmp_path / "config.json").write_text(json.dumps({"seed": 0, "config": no_average}))
    assert TrainConfig.from_dict(run_folder.read_config(tmp_path)["config"]).run.policy_average_from is None
    (tmp_path / "config.json").write_text(json.dumps({"seed": 0, "config": _without(older, "network", "lstm")}))
    with pytest.raises(run_folder.RunFolderError, match="lacks network.lstm"):
        run_folder.read_config(tmp_path)


def test_a_flat_config_json_of_early_versions_is_refused_not_filled_with_defaults(tmp_path, capsys):
    config_json = json.loads(json.dumps(SMOKE.to_dict()))
    flat = {k: v for k, v in config_json.items() if k not in ("acting", "replay", "learner", "run")}
    for group in ("acting", "replay", "learner", "run"):
        flat.update(config_json[group])
    run = tmp_path / "run"
    run.mkdir()
    (run / "config.json").write_text(json.dumps({"seed": 0, "config": flat}))
    err = _refused(["eval", "--run", str(run), "--no-baselines", "--out", str(tmp_path / "eval")], capsys)
    assert "without the groups" in err and "config.json" in err, err


# ============================================================================================ 5. many episodes
class _Compiled:
    """What episodes_that_fit reads of a compiled runner: XLA's memory analysis."""

    def __init__(self, temp, output=0, argument=0):
        self.stats = type(
            "Stats", (), dict(temp_size_in_bytes=temp, output_size_in_bytes=output, argument_size_in_bytes=argument)
        )

    def memory_analysis(self):
        return self.stats


def test_the_episodes_run_side_by_side_are_as_many_as_fit(monkeypatch):
    from ramavt_jax.evaluation import episode_program

    monkeypatch.setattr(memory, "available_bytes", lambda device=None: math.ceil(100 * 2**20 / memory.FRACTION))
    assert episode_program.episodes_that_fit(_Compiled(99 * 2**20, 2**19, 2**19), 1000) == 1000
    assert episode_program.episodes_that_fit(_Compiled(400 * 2**20), 1000) == 250  # 100 MiB at 0.4 MiB per episode
    with pytest.raises(memory.MemoryPlanError, match=r"one evaluation episode needs 200.0 MiB.*resolution"):
        episode_program.episodes_that_fit(_Compiled(2000 * 2**20), 10)
    monkeypatch.setattr(memory, "available_bytes", lambda device=None: None)  # unknown: not planned
    assert episode_program.episodes_that_fit(_Compiled(10 * 2**40), 1000) == 1000


@pytest.mark.slow  # two compiles of the episode runner (about 15 s on 2 busy cores)
def test_episodes_that_do_not_fit_run_in_batches(monkeypatch):
    from ramavt_jax import baselines, render
    from ramavt_jax import env as env_lib
    from ramavt_jax.evaluation import episode_program, rollouts

    tracking_env = env_lib.TrackingEnv(
        env_lib.EnvConfig(camera=render.CameraConfig(resolution=8), targets=("Capsule-v0",))
    )
    params, key, n = tracking_env.eval_params(max_steps=4), jax.random.PRNGKey(1), 12
    policy = baselines.random_policy()
    fn = episode_program.episode_runner(tracking_env, policy, 4, False)
    whole, _ = rollouts.run_episodes(tracking_env, policy, params, key, n)
    mem = episode_program.compiled_runner(fn, params, key, n).memory_analysis()
    need = mem.temp_size_in_bytes + mem.output_size_in_bytes + mem.argument_size_in_bytes
    monkeypatch.setattr(memory, "available_bytes", lambda device=None: int(need / 2.5 / memory.FRACTION))
    batch = episode_program.episodes_that_fit(episode_program.compiled_runner(fn, params, key, n), n)
    assert 1 <= batch < n
    batched, _ = rollouts.run_episodes(tracking_env, policy, params, key, n)
    assert batched.length.shape == (n,)
    for a, b in zip(jax.tree.leaves(batched), jax.tree.leaves(whole)):  # the same episodes, whatever the memory
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


# ============================================================================================ 6. values
@pytest.mark.parametrize("value", ["dt=nan", "speed=inf", "dt=abc", "desired_pos=[0,0,inf]"])
def test_env_params_must_be_finite_numbers(value, tmp_path, capsys):
    err = _refused(TRAIN + ["--env-params", value, "--out", str(tmp_path / "run")], capsys)
    assert f"env_params: {value.split('=')[0]} must be a finite number" in err


@pytest.mark.parametrize("flag", ["--learner.lr", "--learner.max-grad-norm", "--acting.eps-end"])
def test_float_flags_must_be_finite(flag, tmp_path, capsys):
    err = _refused(TRAIN + [flag, "inf", "--out", str(tmp_path / "run")], capsys)
    assert f"{flag.split('.')[-1].replace('-', '_')} must be" in err


@pytest.mark.parametrize("flag", ["--actuator-noise", "--delay-max"])
def test_eval_perturbation_flags_must_be_finite(flag, tmp_path, capsys):
    for value in ("nan", "inf", "-0.5"):
        err = _refused(["eval", "--policy", "random", flag, value, "--out", str(tmp_path / "eval")], capsys)
        assert f"{flag} must be a finite number >= 0" in err


def test_env_overrides_name_the_field():
    from ramavt_jax import env as env_lib

    tracking_env = env_lib.TrackingEnv(env_lib.EnvConfig(targets=("Capsule-v0",)))
    with pytest.raises(ValueError, match="EnvParams.dt must be a number"):
        tracking_env.default_params(dt="abc")
    with pytest.raises(ValueError, match="EnvParams.speed must be finite numbers"):
        tracking_env.default_params(speed=float("inf"))


# ============================================================================================ 7. one writer per --out
def test_a_second_command_on_the_same_out_is_refused(tmp_path, capsys):
    out = tmp_path / "eval"
    out.mkdir()
    with run_folder.RunLock(out):  # the first command, still writing
        err = _refused(["eval", "--policy", "random", "--episodes", "1", "--out", str(out)], capsys)
        assert "in use by process" in err
        err = _refused(["plot", "--runs", str(tmp_path), "--out", str(out)], capsys)
        assert "in use by process" in err
    assert not (out / "tables.md").exists()


# ============================================================================================ signals
@pytest.mark.slow  # a fresh interpreter imports JAX and starts compiling (about 15 s on 2 busy cores)
def test_sigterm_while_compiling_exits_at_once(tmp_path):
    env = dict(os.environ, RAMAVT_COMPILE_CACHE="off", PYTHONPATH=str(Path(cli.__file__).resolve().parents[2]))
    proc = subprocess.Popen(
        [sys.executable, "-m", "ramavt_jax.cli", *TRAIN[:3], "--out", str(tmp_path / "run")],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )
    try:
        for line in proc.stdout:
            if line.startswith("compiling the training chunk"):
                break
        time.sleep(1.0)  # inside XLA's compile
        t = time.time()
        proc.send_signal(signal.SIGTERM)
        code = proc.wait(timeout=30)
        waited = time.time() - t
    finally:
        proc.kill()
    err = proc.stderr.read().strip()
    assert code == 143 and waited < 5, (code, waited, err)
    assert len(err.splitlines()) == 1 and "SIGTERM" in err and "nothing was trained" in err
    assert not (tmp_path / "run" / "config.json").exists()


def test_the_video_trajectory_view_holds_a_far_target():
    from ramavt_jax.figures.episode import EpisodeFrames, view_limits

    def frames(rel_pos):
        t = len(rel_pos)
        return EpisodeFrames(
            obs=None,
            rgb=None,
            rel_pos=np.asarray(rel_pos, float),
            chaser_pos=None,
            target_pos=None,
            reward=np.zeros(t),
            action=np.zeros(t, int),
            alive=np.ones(t, bool),
        )

    assert view_limits(frames([[0.5, 0, 5], [-1, 0, 7]])) == (6.0, 15.0, 6.0)  # the usual view
    half, far, err = view_limits(frames([[0, 0, 5], [30, 0, 100]]))
    assert half >= 30 and far >= 100 and err >= 95


def test_env_params_order_does_not_block_a_resume():
    """A run written with its EnvParams pairs in command-line order resumes under the sorted pairs TrainConfig makes
    now; a changed value still differs."""
    from ramavt_jax.training.run_folder import config_differences

    saved = {"env_params": [["size_scale_min", 0.15], ["size_scale_max", 1.0]], "learner": {"lr": 1e-3}}
    now = {"env_params": [["size_scale_max", 1.0], ["size_scale_min", 0.15]], "learner": {"lr": 1e-3}}
    assert config_differences(saved, now) == {}
    changed = {"env_params": [["size_scale_max", 0.8], ["size_scale_min", 0.15]], "learner": {"lr": 1e-3}}
    assert config_differences(saved, changed) != {}
