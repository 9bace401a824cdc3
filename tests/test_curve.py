"""`ramavt curve`: every checkpoint of a smoke run on the same episodes, its training clock, agreement with
`ramavt eval`, the files it writes and its errors."""

import json

import numpy as np
import pytest

from ramavt_jax import cli
from ramavt_jax.cli import evaluate as cli_eval
from ramavt_jax.evaluation import curve
from ramavt_jax.training import run_folder
from ramavt_jax.training.checkpoint import CheckpointNotFoundError

# tiny evaluations: one target, short episodes; the baselines see 16x16 depth like the smoke run
EPISODES = ["--targets", "Satellite-val0", "--episodes", "2", "--max-steps", "30", "--seed", "3"]


@pytest.fixture(scope="module")
def smoke_run(every_chunk_run):
    return every_chunk_run  # conftest.py


@pytest.fixture(scope="module")
def curve_out(smoke_run, tmp_path_factory):
    """The output folder of `ramavt curve` on the smoke run, without the baselines (compiling the ceiling's search
    costs more than the rest of this file; the slow test below flies them)."""
    out = tmp_path_factory.mktemp("curve_out")
    cli.main(["curve", "--run", str(smoke_run), *EPISODES, "--no-baselines", "--no-progress", "--out", str(out)])
    return out


def test_clock_adds_each_process_compile_once(tmp_path):
    records = [
        {"chunk": 1, "env_steps": 10, "wall_s": 1.0, "compile_s": 30.0},
        {"chunk": 2, "env_steps": 20, "wall_s": 2.0, "compile_s": 30.0},
        {"chunk": 3, "env_steps": 30, "wall_s": 4.0, "compile_s": 5.0},
    ]  # resumed: a second compile
    run_folder.write_metrics(tmp_path / run_folder.METRICS_FILE, records)
    clock = curve.training_clock(tmp_path)
    assert [clock[c]["wall_s"] for c in (1, 2, 3)] == [31.0, 33.0, 42.0]
    assert [clock[c]["env_steps"] for c in (1, 2, 3)] == [10, 20, 30]


def test_clock_counts_from_each_process_start(tmp_path):
    """Records with since_start_s: the process's own clock, a resumed process's added to the earlier total."""
    first, resumed = {"compile_s": 30.0, "started_at": 1e9}, {"compile_s": 30.0, "started_at": 1e9 + 100}
    records = [
        {"chunk": 1, "env_steps": 10, "wall_s": 1.0, "since_start_s": 40.0, **first},
        {"chunk": 2, "env_steps": 20, "wall_s": 2.0, "since_start_s": 43.0, **first},
        {"chunk": 3, "env_steps": 30, "wall_s": 4.0, "since_start_s": 45.0, **resumed},  # a slower start
        {"chunk": 4, "env_steps": 40, "wall_s": 4.0, "since_start_s": 50.0, **resumed},
    ]
    run_folder.write_metrics(tmp_path / run_folder.METRICS_FILE, records)
    clock = curve.training_clock(tmp_path)
    assert [clock[c]["wall_s"] for c in (1, 2, 3, 4)] == [40.0, 43.0, 88.0, 93.0]
    # a run of an earlier version (compile + chunks) resumed by a process that logs since_start_s
    old = {"chunk": 1, "env_steps": 10, "wall_s": 1.0, "compile_s": 30.0}
    run_folder.write_metrics(tmp_path / run_folder.METRICS_FILE, [old, records[2]])
    clock = curve.training_clock(tmp_path)
    assert [clock[c]["wall_s"] for c in (1, 3)] == [31.0, 76.0]


def test_first_above():
    points = [{"step": s, "env_steps": 10 * s, "wall_s": 1.0 * s, "aer": a} for s, a in ((1, -5.0), (2, 3.0), (3, 9.0))]
    assert curve.first_above(points, 0.0) == {"step": 2, "env_steps": 20, "wall_s": 2.0, "aer": 3.0}
    assert curve.first_above(points, 9.0) is None


@pytest.mark.slow
def test_one_row_per_checkpoint_on_the_training_clock(smoke_run, curve_out):
    result = json.loads((curve_out / "curve.json").read_text())
    (run,) = result["runs"]
    points = run["points"]
    assert [p["step"] for p in points] == curve.checkpoint_steps(smoke_run) == [1, 2, 3, 4]
    records = run_folder.read_metrics(smoke_run / run_folder.METRICS_FILE)
    assert [p["env_steps"] for p in points] == [r["env_steps"] for r in records]
    wall = [p["wall_s"] for p in points]
    assert np.all(np.diff(wall) > 0)
    np.testing.assert_allclose(wall, [r["since_start_s"] for r in records])  # the process's clock
    # counted from the `ramavt train` call (made in this process): its compile and chunk, not the pytest run before it
    assert records[0]["compile_s"] + records[0]["wall_s"] <= wall[0] < records[0]["compile_s"] + 120
    for p in points:
        assert p["aer_ci_low"] <= p["aer"] <= p["aer_ci_high"] and 1 <= p["ael"] <= 30
        assert list(p["per_target"]) == ["Satellite-val0"] and p["per_target"]["Satellite-val0"]["aer"] == p["aer"]
    assert result["baselines"] == {} and run["above_depth"] is None
    assert (curve_out / "curve.png").stat().st_size > 0


@pytest.mark.slow
def test_checkpoint_aer_equals_ramavt_eval_on_the_same_episodes(smoke_run, curve_out, tmp_path):
    """The newest checkpoint scored by `ramavt eval` (a greedy policy with its parameters built into the program,
    its own env and keys) gives the curve's number."""
    result = json.loads((curve_out / "curve.json").read_text())
    res = cli_eval.eval_cmd(
        policy="checkpoint",
        run=(smoke_run,),
        baselines=False,
        targets="Satellite-val0",
        episodes=2,
        max_steps=30,
        seed=3,
        tables=(1,),
        speed_steps=0,
        out=tmp_path / "ckpt",
    )
    assert res["rows"][0]["info"]["step"] == 4
    eval_aer = res["rows"][0]["settings"]["none"]["overall"]["return_mean"]
    assert result["runs"][0]["points"][-1]["aer"] == pytest.approx(eval_aer, rel=1e-6)


@pytest.mark.slow
def test_baselines_equal_ramavt_eval_on_the_same_episodes(smoke_run, tmp_path):
    """With the baselines: the depth tracker's and the ceiling's AER are `ramavt eval`'s on the same episodes, and
    the first checkpoint above the tracker is found on them."""
    cli.main(
        [
            "curve",
            "--run",
            str(smoke_run),
            *EPISODES,
            "--resolution",
            "16",
            "--no-progress",
            "--out",
            str(tmp_path / "curve"),
        ]
    )
    result = json.loads((tmp_path / "curve" / "curve.json").read_text())
    assert set(result["baselines"]) == {"depth", "mpc"}
    run = result["runs"][0]
    assert run["above_depth"] == curve.first_above(run["points"], result["baselines"]["depth"]["aer"])
    for policy in ("depth", "mpc"):
        res = cli_eval.eval_cmd(
            policy=policy,
            targets="Satellite-val0",
            episodes=2,
            max_steps=30,
            seed=3,
            tables=(1,),
            resolution=16,
            speed_steps=0,
            out=tmp_path / policy,
        )
        aer = res["rows"][0]["settings"]["none"]["overall"]["return_mean"]
        assert result["baselines"][policy]["aer"] == pytest.approx(aer, rel=1e-6)


def test_the_printed_table(smoke_run, tmp_path, capsys):
    """A second command flies the same episodes (the numbers of the first) and prints one row per checkpoint."""
    cli.main(["curve", "--run", str(smoke_run), *EPISODES, "--no-baselines", "--no-progress", "--out", str(tmp_path)])
    text = capsys.readouterr().out
    rows = [line.split() for line in text.splitlines() if line.strip()[:1].isdigit()]
    assert [r[0] for r in rows] == ["1", "2", "3", "4"] and "AER" in text and "wrote" in text
    result = json.loads((tmp_path / "curve.json").read_text())
    assert [float(r[3]) for r in rows] == [round(p["aer"], 1) for p in result["runs"][0]["points"]]


def test_a_run_without_checkpoints_is_a_one_line_error(smoke_run, tmp_path, capsys):
    empty = tmp_path / "empty"
    empty.mkdir()
    (empty / run_folder.CONFIG_FILE).write_bytes((smoke_run / run_folder.CONFIG_FILE).read_bytes())
    with pytest.raises(CheckpointNotFoundError, match="no checkpoints.*--run.checkpoint-every-chunks 1"):
        curve.checkpoint_steps(empty)
    for run, expected in (
        (empty, "has no checkpoints; train it with --run.checkpoint-every-chunks 1"),
        (tmp_path / "missing", "config.json not found"),
    ):
        with pytest.raises(SystemExit) as e:
            cli.main(["curve", "--run", str(run), "--out", str(tmp_path / "out")])
        assert e.value.code == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and err.startswith("ramavt: error: ") and expected in err, err


def test_chunks_pick_checkpoints_and_a_missing_one_is_a_one_line_error(smoke_run, tmp_path, capsys):
    assert curve.chosen_steps(smoke_run, (3, 1, 3)) == [1, 3] and curve.chosen_steps(smoke_run) == [1, 2, 3, 4]
    out = tmp_path / "two"
    cli.main(
        [
            "curve",
            "--run",
            str(smoke_run),
            *EPISODES,
            "--no-baselines",
            "--no-progress",
            "--chunks",
            "2",
            "4",
            "--out",
            str(out),
        ]
    )
    assert [p["step"] for p in json.loads((out / "curve.json").read_text())["runs"][0]["points"]] == [2, 4]
    capsys.readouterr()
    with pytest.raises(SystemExit) as e:
        cli.main(["curve", "--run", str(smoke_run), *EPISODES, "--chunks", "2", "9", "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err.strip()
    assert e.value.code == 2 and len(err.splitlines()) == 1 and "no checkpoint of chunk(s) [9]" in err, err


def test_a_locked_out_folder_is_refused(smoke_run, tmp_path, capsys):
    with run_folder.RunLock(tmp_path):
        with pytest.raises(SystemExit) as e:
            cli.main(["curve", "--run", str(smoke_run), *EPISODES, "--out", str(tmp_path)])
    assert e.value.code == 2 and "wait for that command to finish" in capsys.readouterr().err
