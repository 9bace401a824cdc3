"""Scale-out: N seeds in one vmapped program, envs and replay sharded over (forced CPU) devices, multi-host on
loopback. Device counts are fixed when JAX starts, so the sharded and multi-host checks run in subprocesses with
XLA_FLAGS=--xla_force_host_platform_device_count=N."""

import json
import os
import socket
import subprocess
import sys
from pathlib import Path

import jax
import numpy as np
import pytest

from ramavt_jax import distributed
from ramavt_jax.presets import preset
from ramavt_jax.training import driver as train_log

ROOT = Path(__file__).resolve().parents[1]
SMOKE = preset("smoke", eval_episodes=0, checkpoint_every_chunks=1)


def _env(devices: int) -> dict:
    env = dict(os.environ)
    env["XLA_FLAGS"] = f"--xla_force_host_platform_device_count={devices}"
    env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    for k in ("JAX_COORDINATOR_ADDRESS", "JAX_NUM_PROCESSES", "JAX_PROCESS_ID"):
        env.pop(k, None)
    return env


def _worker(*args, devices=4, timeout=900) -> dict:  # compiles from scratch: minutes on a loaded 2-core machine
    proc = subprocess.run(
        [sys.executable, str(ROOT / "tests" / "distributed_worker.py"), *map(str, args)],
        env=_env(devices),
        capture_output=True,
        text=True,
        timeout=timeout,
    )
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("RESULT ")]
    assert proc.returncode == 0 and lines, f"worker failed ({proc.returncode}):\n{proc.stderr[-3000:]}"
    return json.loads(lines[-1][len("RESULT ") :])


# ============================================================================================ devices
# Slow (about 100 s on an idle 2-core machine: two compiles of the chunk on 4 forced devices).
@pytest.mark.slow
def test_sharded_run_equals_unsharded_run_and_uses_every_device():
    r = _worker("shard", 2)
    assert r["device_count"] == 4
    assert r["updates"] > 0  # the learner really ran (learning_starts is passed inside the 2 chunks)
    # same global batch, same keys: equal up to float summation order (the all-reduced gradient)
    assert r["params_max_diff"] < 1e-4 * max(1.0, r["params_max_abs"]), r["params_max_diff"]
    np.testing.assert_allclose(r["loss_sharded"], r["loss_single"], rtol=1e-4)
    # envs (observation, env state, LSTM carry) and replay rows are split 4 ways along the env axis (8 envs)
    for name, shard in (
        ("obs", [2, 16, 16, 1]),
        ("env_pos", [2, 3]),
        ("lstm_h", [1, 2, 32]),
        ("replay_obs", [2, 100, 16, 16, 1]),
    ):
        p = r[name]
        assert p["devices"] == [0, 1, 2, 3] and p["distinct_shards"] == 4 and not p["replicated"], (name, p)
        assert p["shard_shapes"] == [shard], (name, p)
    # params are replicated on every device
    assert r["param"]["replicated"] and r["param"]["devices"] == [0, 1, 2, 3]


def test_env_batch_that_does_not_divide_over_devices_is_a_clear_error():
    r = _worker("indivisible", devices=3, timeout=120)
    assert r["error"] is not None
    assert "num_envs=8 does not divide over 3 devices" in r["error"] and "--devices" in r["error"]


# Slow (the default suite's costliest test on a 2-core machine, about 2 min: a 4-device compile in a subprocess);
# the default suite keeps the vmapped seeds' equality with single-seed runs and the indivisible-batch error.
@pytest.mark.slow
def test_seeds_are_split_over_devices_whole():
    r = _worker("seeds", devices=2)
    assert r["obs_devices"] == 2 and r["obs_shard_shapes"] == [[1, 8, 16, 16, 1]]  # one whole seed per device
    assert r["params_max_diff"] < 1e-5, r["params_max_diff"]
    assert r["three_seeds_error"] is not None and "multiple of 2" in r["three_seeds_error"]


def test_single_device_mesh_is_the_plain_program():
    assert distributed.make_mesh() is None  # this test process sees one CPU device
    with pytest.raises(ValueError, match="device"):
        distributed.make_mesh(2)
    distributed.check_divisible(7, None)  # nothing to split: no error


def test_initialize_validates_its_arguments(monkeypatch):
    for k in ("JAX_COORDINATOR_ADDRESS", "JAX_NUM_PROCESSES", "JAX_PROCESS_ID"):
        monkeypatch.delenv(k, raising=False)
    assert distributed.initialize() is False  # no coordinator: single process, nothing started
    with pytest.raises(ValueError, match="without a coordinator"):
        distributed.initialize(num_processes=2, process_id=1)
    with pytest.raises(ValueError, match="process count and id are missing"):
        distributed.initialize("127.0.0.1:1234")
    with pytest.raises(ValueError, match="process_id < num_processes"):
        distributed.initialize("127.0.0.1:1234", 2, 2)
    monkeypatch.setenv("JAX_COORDINATOR_ADDRESS", "localhost")
    monkeypatch.setenv("JAX_NUM_PROCESSES", "2")
    monkeypatch.setenv("JAX_PROCESS_ID", "0")
    with pytest.raises(ValueError, match="host:port"):
        distributed.initialize()


# ============================================================================================ seeds
def _params(summary, k=None):
    p = summary.state.learner.params
    return p if k is None else jax.tree.map(lambda x: x[k], p)


@pytest.mark.slow
def test_vmapped_seeds_equal_single_seed_runs_and_write_per_seed_folders(tmp_path):
    singles = [train_log.run(SMOKE, tmp_path / f"single_{s}", seed=s, progress=False) for s in (3, 4)]
    # two seeds in ONE program, split into two calls to check the multi-seed resume as well
    part = train_log.run(SMOKE, tmp_path / "multi", seed=3, num_seeds=2, progress=False, max_chunks=2)
    assert part["chunks_done"] == 2 and len(part["seeds"]) == 2
    both = train_log.run(SMOKE, tmp_path / "multi", seed=3, num_seeds=2, progress=False)
    assert both["chunks_done"] == SMOKE.num_chunks
    for k, single in enumerate(singles):
        for a, b in zip(jax.tree.leaves(_params(both, k)), jax.tree.leaves(_params(single))):
            np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-4, atol=1e-5)
        run_dir = tmp_path / "multi" / f"seed_{3 + k}"
        mine = train_log.read_metrics(run_dir / "metrics.jsonl")
        ref = train_log.read_metrics(tmp_path / f"single_{3 + k}" / "metrics.jsonl")
        assert [r["chunk"] for r in mine] == list(range(1, SMOKE.num_chunks + 1))
        np.testing.assert_allclose([r["loss"] for r in mine], [r["loss"] for r in ref], rtol=1e-4)
        assert json.loads((run_dir / "config.json").read_text())["seed"] == 3 + k
        assert (run_dir / "checkpoints" / str(SMOKE.num_chunks)).is_dir()
    # the seeds really differ (own keys, own envs, own replay)
    diff = max(
        float(np.abs(np.asarray(a) - np.asarray(b)).max())
        for a, b in zip(jax.tree.leaves(_params(both, 0)), jax.tree.leaves(_params(both, 1)))
    )
    assert diff > 1e-3
    mem = both["memory"]
    assert mem["replay_bytes_per_seed"] > 0 and mem["state_bytes_per_seed"] > mem["replay_bytes_per_seed"]
    with pytest.raises(ValueError, match="num_seeds"):
        train_log.run(SMOKE, tmp_path / "bad", num_seeds=0, progress=False)


# ============================================================================================ hosts
def _free_port() -> int | None:
    try:
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
            s.bind(("127.0.0.1", 0))
            return s.getsockname()[1]
    except OSError:
        return None


# Slow: two training processes and a reference run (about 100 s idle, 300 s on a loaded 2-core machine).
@pytest.mark.slow
def test_two_process_run_on_loopback_matches_a_single_process_run(tmp_path):
    port = _free_port()
    if port is None:
        pytest.skip("cannot open a loopback port here")
    out = tmp_path / "multihost"
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
        "--coordinator-address",
        f"127.0.0.1:{port}",
        "--num-processes",
        "2",
    ]
    procs = [
        subprocess.Popen(
            cmd + ["--process-id", str(i)], env=_env(2), stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
        )
        for i in range(2)
    ]
    logs = []
    try:
        for p in procs:
            logs.append(p.communicate(timeout=400)[0])
    except subprocess.TimeoutExpired:
        for p in procs:
            p.kill()
        pytest.fail("the two-process run did not finish in 400 s")
    for i, (p, log) in enumerate(zip(procs, logs)):
        assert p.returncode == 0, f"process {i} failed:\n{log[-3000:]}"
    assert "on 4 device(s), 2 process(es)" in logs[0]  # process 0 reports; it saw both processes' devices
    records = train_log.read_metrics(out / "metrics.jsonl")
    assert [r["chunk"] for r in records] == list(range(1, SMOKE.num_chunks + 1))
    assert (out / "checkpoints" / str(SMOKE.num_chunks)).is_dir()
    # the same global batch on one device in this process gives the same learning curve
    ref = train_log.run(SMOKE, tmp_path / "reference", seed=0, progress=False)
    ref_records = train_log.read_metrics(Path(ref["out_dir"]) / "metrics.jsonl")
    np.testing.assert_allclose([r["loss"] for r in records], [r["loss"] for r in ref_records], rtol=1e-3)
    np.testing.assert_allclose([r["q_mean"] for r in records], [r["q_mean"] for r in ref_records], rtol=1e-3)
