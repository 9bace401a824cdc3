"""Fault injection, round 3 (issue 60), one test per failure met: a full disk while results, checkpoints and metrics
are written, a second command on a folder still being evaluated, metrics rows lost beside their checkpoints, a
diverging learner, settings outside their ranges, a config.json that no longer fits its checkpoints, a second
Ctrl-C while a checkpoint is written, and the messages of tyro, of a damaged metrics file, of a resized split and of
a weightless model. Each ends in exit status 2 with one line on stderr, or in success with nothing lost."""

import dataclasses
import errno
import json
import logging
import os
import shutil
import signal
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from ramavt_jax import cli, env
from ramavt_jax.evaluation import final, report, rollouts
from ramavt_jax.evaluation import tables as tables_lib
from ramavt_jax.presets import PRESETS, preset
from ramavt_jax.train import Trainer
from ramavt_jax.training import driver, files, metrics, run_folder
from ramavt_jax.training.checkpoint import CheckpointError, CheckpointStore, CheckpointWriteError

TRAIN = ["train", "--preset", "smoke", "--no-progress"]
# the package fixture every_chunk_run's config (tests/conftest.py): a checkpoint after each of its 4 chunks
EVERY_CHUNK = preset("smoke", eval_episodes=0, checkpoint_every_chunks=1, keep_checkpoints=100, checkpoint_replay=False)
ENOSPC = OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))


def _one_line(args, capsys) -> str:
    """Run the CLI in-process: exit status 2 and exactly one line on stderr, no traceback."""
    with pytest.raises(SystemExit) as e:
        cli.main(args)
    err = capsys.readouterr().err.strip()
    assert e.value.code == 2, err
    assert len(err.splitlines()) == 1 and err.startswith("ramavt: error: ") and "Traceback" not in err, err
    return err


def _copy(run: Path, tmp_path: Path) -> Path:
    out = tmp_path / "run"
    shutil.copytree(run, out)
    return out


def _rows(path: Path) -> list[dict]:
    return [json.loads(line) for line in path.read_text().splitlines()]


# ============================================================================================ 1. full disk
def _disk_full_for(monkeypatch, word: str) -> None:
    """Every temporary file whose name holds ``word`` gets its first 4,096 bytes, then ENOSPC (a full disk)."""
    real = Path.write_text

    def write_text(self, text, *args, **kwargs):
        if self.name.startswith(".") and word in self.name:
            real(self, text[:4096], *args, **kwargs)
            raise ENOSPC
        return real(self, text, *args, **kwargs)

    monkeypatch.setattr(Path, "write_text", write_text)


def _no_temporary_files(folder: Path) -> None:
    assert not [p.name for p in folder.iterdir() if ".tmp" in p.name]


def test_a_full_disk_leaves_the_earlier_tables_whole_and_agreeing(tmp_path, capsys, monkeypatch):
    out = tmp_path / "eval"
    result = {"settings": {"perturbation_settings": ["none"]}, "rows": list(range(2000))}  # results.json > 4 kB
    monkeypatch.setattr(report, "to_markdown", lambda result, command: f"# {len(result['rows'])} rows\n")
    monkeypatch.setattr(report.seeds, "summarise_arms", lambda result, setting: {})
    report.write(result, out)
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    _disk_full_for(monkeypatch, "results")
    with pytest.raises(files.WriteError, match=r"cannot write .*results.json: No space left on device"):
        report.write({**result, "rows": [0]}, out)
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before  # tables.md was not replaced alone either
    _no_temporary_files(out)
    # the same through `ramavt eval --out EXISTING`: one line, the earlier files kept
    monkeypatch.setattr(tables_lib, "run_suite", lambda *args, **kw: {**result, "rows": [1]})
    err = _one_line(["eval", "--policy", "random", "--episodes", "1", "--out", str(out)], capsys)
    assert "results.json: No space left on device" in err and "left as they were" in err
    assert {p.name: p.read_bytes() for p in out.iterdir() if p.name != ".lock"} == before


def test_a_full_disk_leaves_the_earlier_eval_json(tmp_path, monkeypatch):
    monkeypatch.setattr(final, "final_evaluation", lambda config, params, key, log: {"val": {"greedy": "x" * 5000}})
    final.evaluate_run(EVERY_CHUNK, tmp_path, 0, None, log=lambda msg: None)
    before = (tmp_path / run_folder.EVAL_FILE).read_bytes()
    _disk_full_for(monkeypatch, "eval")
    with pytest.raises(files.WriteError, match="eval.json: No space left on device"):
        final.evaluate_run(EVERY_CHUNK, tmp_path, 0, None, log=lambda msg: None)
    assert (tmp_path / run_folder.EVAL_FILE).read_bytes() == before
    _no_temporary_files(tmp_path)


def test_every_file_the_package_writes_goes_through_the_one_writer():
    """A write call in the package names a temporary file of files.replace_files (``tmp``), except the two
    appends of run_folder itself (metrics rows, the lock file)."""
    import re

    root = Path(run_folder.__file__).resolve().parents[1]
    write = re.compile(
        r"\.(write_text|write_bytes|savefig|mimsave|savez|savez_compressed|imwrite)\(|open\([^)]*[\"'][wax]"
    )
    found = []
    for path in root.rglob("*.py"):
        for i, line in enumerate(path.read_text().splitlines(), 1):
            if write.search(line) and "tmp" not in line and not line.lstrip().startswith("#"):
                found.append(f"{path.relative_to(root)}:{i}: {line.strip()}")
    allowed = {"training/run_folder.py"}
    assert [f for f in found if f.split(":")[0] not in allowed] == []


def test_a_full_disk_during_a_checkpoint_is_one_line_and_keeps_the_earlier_ones(tmp_path, monkeypatch, caplog):
    store = CheckpointStore(tmp_path / "checkpoints", keep=3)
    state = {"w": np.arange(4.0, dtype=np.float32)}
    store.save(1, state, {"chunk": 1})

    def full(step, args, force):  # what orbax and tensorstore do when the disk fills: a temporary folder, noise
        (store.directory / f"{step}.orbax-checkpoint-tmp-1").mkdir()
        logging.getLogger("absl").error("_SignalingThread.run() raised an exception: RESOURCE_EXHAUSTED")
        raise ValueError(
            'RESOURCE_EXHAUSTED: Error writing "00002/0.0.0.0" in OCDBT database: Failed to write 55712 bytes to '
            "file 15: No space left on device [os_error_code='28']"
        )

    monkeypatch.setattr(store.manager, "save", full)
    with caplog.at_level(logging.ERROR), pytest.raises(CheckpointWriteError) as e:
        store.save(2, state, {"chunk": 2})
    assert e.value.errno == errno.ENOSPC and "\n" not in str(e.value)
    assert str(e.value).startswith(f"cannot write checkpoint 2 in {store.directory}: No space left on device")
    assert "newest: 1" in str(e.value) and "RESOURCE_EXHAUSTED" not in caplog.text
    assert [p.name for p in store.directory.iterdir()] == ["1"]  # the temporary folder's space is back


def test_a_full_disk_while_training_is_one_line_and_the_run_resumes(tmp_path, capsys, monkeypatch, every_chunk_run):
    """(The fixture compiles the smoke program this test reuses.) The checkpoint of chunk 3 hits a full disk."""
    real = CheckpointStore.save

    def save(self, step, state, meta, force=True):
        if step == 3:
            raise CheckpointWriteError(errno.ENOSPC, f"cannot write checkpoint 3 in {self.directory}: No space left")
        return real(self, step, state, meta, force)

    monkeypatch.setattr(CheckpointStore, "save", save)
    out = tmp_path / "run"
    args = TRAIN + ["--out", str(out), "--run.eval-episodes", "0", "--run.checkpoint-every-chunks", "1"]
    err = _one_line(args, capsys)
    assert "cannot write checkpoint 3" in err
    monkeypatch.setattr(CheckpointStore, "save", real)
    cli.main(args)  # the room is back: the run resumes from chunk 2
    assert [r["chunk"] for r in _rows(out / run_folder.METRICS_FILE)] == [1, 2, 3, 4]


# ============================================================================================ 2. the lock
def test_the_run_folder_stays_locked_through_the_final_evaluation(tmp_path, capsys, monkeypatch):
    """A second `ramavt train --no-resume` started while the first evaluates its run is refused in one line."""
    from ramavt_jax import experiment

    def fake_run(config, out, **kwargs):
        summary = driver.RunSummary(seed=0, out_dir=str(out), last=None, finished=True)
        summary.state = None
        return summary

    refused = []

    def evaluate(config, run_dir, seed, params, log):
        refused.append(_one_line(TRAIN + ["--no-resume", "--learner.lr", "0.002", "--out", str(run_dir)], capsys))

    monkeypatch.setattr(experiment.driver, "run", fake_run)
    monkeypatch.setattr(experiment.host_state, "seed_params", lambda *args: None)
    monkeypatch.setattr(experiment, "evaluate_run", evaluate)
    experiment.train_and_evaluate(preset("smoke"), tmp_path / "run", progress=False)
    assert len(refused) == 1 and "in use by process" in refused[0]
    with run_folder.RunLock(tmp_path / "run"):  # and let go once the command is done
        pass


# ============================================================================================ 3. metrics rows
def test_rows_lost_beside_their_checkpoints_are_rebuilt_from_them(tmp_path, capsys, every_chunk_run):
    out = _copy(every_chunk_run, tmp_path)
    path = out / run_folder.METRICS_FILE
    whole = path.read_text()
    cut = whole.index('{"chunk": 3') + 20
    path.write_text(whole[:cut])  # a power cut: row 3 torn, row 4 gone, checkpoints 3 and 4 on disk
    driver.run(EVERY_CHUNK, out, progress=False)
    said = capsys.readouterr().out
    assert path.read_text() == whole
    assert "skipped its last line" in said and "rebuilt the row(s) of chunk(s) 3, 4 from checkpoint 4" in said


def test_a_row_that_cannot_be_rebuilt_is_refused_in_one_line(tmp_path):
    path = tmp_path / run_folder.METRICS_FILE
    run_folder.write_metrics(path, [{"chunk": 1, "loss": 0.5}, {"chunk": 3, "loss": None}])
    asked = []
    rows = run_folder.resumed_rows(path, 1, lambda: asked.append(1), log=lambda msg: None)
    assert [r["chunk"] for r in rows] == [1] and asked == []  # complete: the checkpoints are not read
    saved = [{"chunk": 2, "loss": 0.25}]
    rows = run_folder.resumed_rows(path, 3, lambda: saved, log=lambda msg: None)
    assert [r["chunk"] for r in rows] == [1, 2, 3] and np.isnan(rows[2]["loss"])
    path.write_text(path.read_text().splitlines()[1] + "\n")  # row 1 lost, and no checkpoint holds it
    with pytest.raises(run_folder.RunFolderError, match=r"lacks the rows of chunk\(s\) 1, 2, which checkpoint 3") as e:
        run_folder.resumed_rows(path, 3, None, log=lambda msg: None)
    assert "--no-resume" in str(e.value) and "\n" not in str(e.value)


def test_rows_are_flushed_before_the_checkpoint_that_holds_them(tmp_path, monkeypatch, every_chunk_run):
    events = []
    real_sync, real_save = files.fsync_file, CheckpointStore.save
    monkeypatch.setattr(files, "fsync_file", lambda p: events.append(("sync", Path(p).name)) or real_sync(p))

    def save(self, step, state, meta, force=True):
        events.append(("save", step, [r["chunk"] for r in meta["metrics"]]))
        return real_save(self, step, state, meta, force)

    monkeypatch.setattr(CheckpointStore, "save", save)
    driver.run(EVERY_CHUNK.override(checkpoint_every_chunks=2), tmp_path / "run", progress=False)
    saves = [(i, e) for i, e in enumerate(events) if e[0] == "save"]
    assert [e for _, e in saves] == [("save", 2, [1, 2]), ("save", 4, [3, 4])]
    assert all(events[i - 1] == ("sync", run_folder.METRICS_FILE) for i, _ in saves)


# ============================================================================================ 4. divergence
def test_the_divergence_guard_reads_the_gradient_norm_and_the_loss_bound():
    healthy = {"updates": 5, "loss": 2.0, "q_mean": 1.0, "grad_norm": 3.0}
    assert metrics.divergence(healthy, 1e10) is None
    assert metrics.divergence({**healthy, "updates": 0, "loss": float("nan"), "grad_norm": float("nan")}) is None
    assert metrics.divergence({**healthy, "grad_norm": float("nan")}) == "grad_norm=nan is not a finite number"
    assert metrics.divergence({**healthy, "loss": 6e29}, 1e10) == "loss=6e+29 is above run.max_loss=1e+10"
    assert metrics.divergence({**healthy, "loss": 6e29}, None) is None
    with pytest.raises(ValueError, match="max_loss must be > 0"):
        preset("smoke", max_loss=0.0)


def test_a_loss_above_the_bound_stops_training_in_one_line(tmp_path, capsys, every_chunk_run):
    out = tmp_path / "run"
    err = _one_line(TRAIN + ["--out", str(out), "--run.eval-episodes", "0", "--run.max-loss", "1e-9"], capsys)
    assert "training diverged at chunk" in err and "is above run.max_loss=1e-09" in err and "grad_norm=" in err
    assert not (out / run_folder.EVAL_FILE).exists()


# ============================================================================================ 5. ranges
@pytest.mark.parametrize(
    "pair, words",
    [
        ("dt=1e9", "dt must be in (0, 1] s"),
        ("speed=100", "speed must be in (0, 10] m/s"),
        ("max_steps=99999999999", "max_steps must be a whole number in [1, 1000000]"),
        ("mean_motion=1", "mean_motion must be in [0, 0.01] rad/s"),
        ("blur_frames=3", "blur_frames must be a whole number in [1, EnvConfig.frame_history=1]"),
        ("desired_pos=[0,0,50]", "desired_pos must be in view"),
        ("init_z_min=0.01", "init_z_min must be in (camera.near=0.05, 1000] m"),
    ],
)
def test_settings_outside_their_ranges_are_refused_in_one_line(pair, words, tmp_path, capsys):
    err = _one_line(TRAIN + ["--env-params", pair, "--out", str(tmp_path / "run")], capsys)
    assert f"env_params: {words}" in err
    assert not (tmp_path / "run").exists()


def test_every_setting_has_a_range_that_holds_the_presets_and_the_evaluation_settings():
    from ramavt_jax.env_config import RANGES

    traced = {f.name for f in dataclasses.fields(env.EnvParams)} - {
        "catalogue",
        "target_probs",
        "desired_pos",
        "sun_dir",
    }
    assert traced == set(RANGES)
    for name in PRESETS:
        config = preset(name)
        tracking_env = env.TrackingEnv(config.env)
        tracking_env.default_params(**dict(config.env_params))
        tracking_env.eval_params(**rollouts.run_env_overrides(config.env_params))
    blurred = env.TrackingEnv(env.EnvConfig(targets=("Capsule-v0",), frame_history=3))
    for setting in rollouts.PERTURBATIONS:
        blurred.eval_params(**rollouts.perturbation_overrides(setting))
    with pytest.raises(ValueError, match=r"EnvParams.dt must be in \(0, 1\] s"):
        blurred.default_params(dt=1e9)


# ============================================================================================ 6. config and checkpoints
def test_a_config_json_that_no_longer_fits_its_checkpoints_is_one_line_for_eval_and_train(
    tmp_path, capsys, every_chunk_run
):
    out = _copy(every_chunk_run, tmp_path)
    saved = json.loads((out / run_folder.CONFIG_FILE).read_text())
    saved["config"]["network"]["lstm"] = 16  # edited
    (out / run_folder.CONFIG_FILE).write_text(json.dumps(saved))
    args = ["eval", "--run", str(out), "--no-baselines", "--tables", "1", "--out", str(tmp_path / "eval")]
    err = _one_line(args, capsys)
    words = "does not fit the config it is read with"
    assert words in err and "the checkpoint's config differs in network.lstm" in err and "--no-resume" in err
    # train's restore reads the same check, in the same words
    edited = EVERY_CHUNK.override(network=dataclasses.replace(EVERY_CHUNK.network, lstm=16))
    like = jax.eval_shape(Trainer(edited).init, jax.ShapeDtypeStruct((2,), jnp.uint32)).replace(replay=None)
    store = CheckpointStore(out / run_folder.CHECKPOINTS, create=False)
    with pytest.raises(CheckpointError, match=words) as e:
        store.restore_newest_loadable(like, config=saved["config"])
    assert "differs in network.lstm" in str(e.value) and "\n" not in str(e.value)
    assert store.all_steps() == [1, 2, 3, 4]  # refused, not taken for damage: nothing deleted


# ============================================================================================ 7. interrupts
def test_a_second_ctrl_c_while_a_checkpoint_is_written_waits_for_it(tmp_path, monkeypatch, every_chunk_run):
    real = CheckpointStore.save

    def save(self, step, state, meta, force=True):
        if step == 2:  # a Ctrl-C, then another, while checkpoint 2 is written
            os.kill(os.getpid(), signal.SIGINT)
            os.kill(os.getpid(), signal.SIGINT)
        return real(self, step, state, meta, force)

    monkeypatch.setattr(CheckpointStore, "save", save)
    out = tmp_path / "run"
    with pytest.raises(KeyboardInterrupt):
        driver.run(EVERY_CHUNK, out, progress=False)
    monkeypatch.setattr(CheckpointStore, "save", real)
    assert CheckpointStore(out / run_folder.CHECKPOINTS, create=False).all_steps() == [1, 2]
    assert [r["chunk"] for r in _rows(out / run_folder.METRICS_FILE)] == [1, 2]
    rest = driver.run(EVERY_CHUNK, out, progress=False)  # checkpoint 2 is whole: the run goes on from it
    assert rest["chunks_done"] == 4 and [r["chunk"] for r in _rows(out / run_folder.METRICS_FILE)] == [1, 2, 3, 4]


# ============================================================================================ 8. messages
@pytest.mark.parametrize(
    "args, words",
    [
        (
            TRAIN + ["--learner.lrr", "3"],
            "unrecognized option --learner.lrr for `ramavt train` (did you mean --learner.lr?)",
        ),
        (["eval", "--episodes", "abc"], "--episodes expects INT: invalid literal for int()"),
        (["eval", "--policy", "best"], "--policy must be one of checkpoint, pretrained, mpc"),
        (["evl"], "unknown command 'evl' (did you mean eval?)"),
        (TRAIN + ["--resume", "3"], "unexpected value '3'"),
        (["eval", "--policy", "random", "--episodes", "99999999999"], "--episodes must be an integer in [1, 1000000]"),
        (["eval", "--policy", "random", "--delay-max", "1e9"], "--delay-max: EnvParams.delay_max must be in [0, 10] s"),
    ],
)
def test_a_mistyped_flag_or_value_is_one_line(args, words, capsys):
    assert words in _one_line(args, capsys)


def test_a_byte_that_is_not_utf8_names_the_metrics_file_and_line(tmp_path):
    path = tmp_path / run_folder.METRICS_FILE
    rows = b'{"chunk": 1}\n{"chunk": 2}\n{"chunk": 3}\n'
    path.write_bytes(rows.replace(b'"chunk": 2', b'"chunk": \xfe2'))
    with pytest.raises(run_folder.RunFolderError) as e:
        run_folder.read_metrics(path)
    assert f"{path} line 2 is not a JSON record (byte 0xfe at column 11 is not UTF-8 text)" in str(e.value)
    path.write_bytes(rows + b'{"chunk": \xfe')  # in a torn last line: skipped like any torn line
    assert [r["chunk"] for r in run_folder.read_metrics(path, log=lambda msg: None)] == [1, 2, 3]


def test_a_split_takes_a_size_suffix():
    from ramavt_jax import targets

    resized = rollouts.resolve_targets("val@0.3m")
    assert resized == tuple(f"{name}@0.3m" for name in targets.split("val"))
    with pytest.raises(targets.TargetError, match="'val-sizes' holds resized models already"):
        rollouts.resolve_targets("val-sizes@0.3m")
    with pytest.raises(targets.TargetError, match="from 0.* to .* such as 'val@0.3m'"):
        rollouts.resolve_targets("val@1e9m")


def test_a_weightless_model_inside_a_body_gets_the_right_hint(tmp_path):
    from ramavt_jax import targets

    path = tmp_path / "weightless.xml"
    path.write_text('<mujoco><worldbody><body><geom type="sphere" size="1" density="0"/></body></worldbody></mujoco>')
    with pytest.raises(targets.TargetError, match='zero mass .*density="0".*give the geoms a density or a mass'):
        targets.load_numpy(str(path))
    path.write_text('<mujoco><worldbody><geom type="sphere" size="1"/></worldbody></mujoco>')
    with pytest.raises(targets.TargetError, match=r"zero mass; put the geoms in a <body> \(not <worldbody> directly"):
        targets.load_numpy(str(path))


@pytest.mark.slow  # a fresh interpreter imports JAX and compiles the smoke program (about 25 s on 2 busy cores)
@pytest.mark.parametrize("gap_s", [0.0, 0.3])
def test_a_double_ctrl_c_is_one_line_and_the_run_resumes(gap_s, tmp_path):
    """Two SIGINTs ``gap_s`` apart while training (the second may land in a checkpoint or in the shutdown)."""
    import subprocess
    import sys
    import time

    out = tmp_path / "run"
    env_vars = dict(os.environ, PYTHONPATH=str(Path(cli.__file__).resolve().parents[2]))
    args = TRAIN + ["--out", str(out), "--run.total-env-steps", "64000", "--run.checkpoint-every-chunks", "1"]
    args += ["--run.eval-episodes", "0"]
    proc = subprocess.Popen(
        [sys.executable, "-m", "ramavt_jax.cli", *args], stderr=subprocess.PIPE, text=True, env=env_vars
    )
    try:
        rows = out / run_folder.METRICS_FILE
        while not (rows.exists() and len(rows.read_text().splitlines()) >= 3) and proc.poll() is None:
            time.sleep(0.05)
        proc.send_signal(signal.SIGINT)
        time.sleep(gap_s)
        proc.send_signal(signal.SIGINT)
        err = proc.communicate(timeout=120)[1].strip()
    finally:
        proc.kill()
    assert proc.returncode in (130, -signal.SIGINT), err  # -2: the second came after Python restored the default
    assert len(err.splitlines()) == 1 and err.startswith("ramavt: ") and "Traceback" not in err, err
    done = CheckpointStore(out / run_folder.CHECKPOINTS, create=False).latest_step()
    assert [r["chunk"] for r in _rows(rows)][:done] == list(range(1, done + 1))
    summary = driver.run(
        preset("smoke", total_env_steps=64000, checkpoint_every_chunks=1, eval_episodes=0),
        out,
        progress=False,
        max_chunks=1,
    )
    assert summary["chunks_done"] == done + 1
