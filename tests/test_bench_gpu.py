"""The accelerator check (benchmarks/bench_gpu.py): its order, deadline, error rows and report, with the measurements
stubbed (fast); the real thing at toy sizes on CPU is marked slow."""

import json
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import bench_gpu  # noqa: E402


def test_plan_puts_the_64x64_env_sweep_first_then_the_presets():
    items = bench_gpu.plan()
    assert items[:4] == [("env", "depth", 64, n) for n in (1024, 4096, 16384, 65536)]
    assert items[4:6] == [("chunk", "quick"), ("chunk", "paper")]


def test_a_failing_item_is_recorded_and_late_items_are_skipped(tmp_path, monkeypatch):
    now = [0.0]

    def fake_measure(item, budget_s, chunks):
        now[0] += 100.0  # every item takes 100 s of the deadline
        if item == ("env", "depth", 64, 65536):
            raise RuntimeError("RESOURCE_EXHAUSTED: out of memory\nallocator details")
        if item[0] == "env":
            return {"env_steps_per_s": 1e6 * item[3] / 65536, "compile_s": 3.0}
        return {
            "num_envs": 64,
            "resolution": 32,
            "batch_size": 32,
            "env_steps_per_s": 9000.0,
            "updates_per_s": 30.0,
            "trained_frames_per_s": 19200.0,
            "chunk_s": [3.5, 3.6],
            "compile_s": 40.0,
            "projected_train_wall_s": 60.0,
        }

    monkeypatch.setattr(bench_gpu, "_measure", fake_measure)
    result = bench_gpu.run(str(tmp_path), deadline_s=550.0, min_left_s=60.0, clock=lambda: now[0])
    rows = result["items"]
    assert json.loads((tmp_path / "results_gpu.json").read_text()) == result  # written as it went
    assert rows[3]["error"] == "RuntimeError: RESOURCE_EXHAUSTED: out of memory"  # one line, and the run went on
    assert "env_steps_per_s" in rows[2] and "skipped" not in rows[2]
    assert "skipped" in rows[5] and all("skipped" in r for r in rows[5:])  # 500 s used: 50 s < 60 s left
    assert "env_steps_per_s" in rows[4]  # the quick preset still ran (150 s left)
    text = bench_gpu.report(result)
    assert "| depth | 64 | 4096 | 62,500 | 3.0 |" in text
    assert "RESOURCE_EXHAUSTED" in text
    assert "| quick | 64 | 32 | 32 | 9,000 | 30.00 | 19,200 | 3.5, 3.6 | 40 | 1.0 min |" in text
    assert text.count("left before the deadline") == len(rows) - 5


@pytest.mark.slow  # compiles an env step and a smoke training chunk (about 1 min on an idle 2-core machine)
def test_the_check_runs_end_to_end_at_toy_sizes(tmp_path):
    result = bench_gpu.run(str(tmp_path), smoke=True, budget_s=0.2)
    env, chunk = result["items"]
    assert env["env_steps_per_s"] > 0 and chunk["updates_per_s"] > 0 and chunk["trained_frames_per_s"] > 0
    assert chunk["compile_s"] > 0 and len(chunk["chunk_s"]) == 2
    assert chunk["projected_train_wall_s"] > chunk["compile_s"] + sum(chunk["chunk_s"])  # the whole run > 2 chunks
    assert result["device"]["backend"] == "cpu" and "cpu" in bench_gpu.report(result)
