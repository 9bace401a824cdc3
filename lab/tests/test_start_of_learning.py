"""lab/start_of_learning.py: each seed's first chunk above the depth tracker, the arms' table and figure, and
curves flown on different episodes refused."""

import json
from pathlib import Path

import pytest

from lab import start_of_learning  # noqa: E402

EPISODES = {"targets": ["Satellite-val0"], "episodes_per_target": 2, "seed": 0}


def _curve(path: Path, runs: list[dict], episodes=EPISODES) -> str:
    result = {
        "episodes": episodes,
        "baselines": {"depth": {"aer": 100.0}},
        "runs": [{"points": [{"step": c, "aer": a} for c, a in run.items()]} for run in runs],
    }
    path.write_text(json.dumps(result))
    return str(path)


def test_first_chunk_above_per_seed_over_the_shared_chunks(tmp_path, capsys):
    a = _curve(tmp_path / "a.json", [{6: 50.0, 7: 150.0, 8: 90.0}, {6: -5.0, 7: 20.0, 8: 101.0, 9: 300.0}])
    b = _curve(tmp_path / "b.json", [{6: 120.0, 7: 130.0}])
    start_of_learning.main([f"A={a}", f"B={b}", "--out", str(tmp_path / "fig.png")])
    out = capsys.readouterr().out
    assert "| A | 2 | 7, 8 | 6: +22.5, 7: +85.0, 8: +95.5 |" in out  # the mean: chunk 9 is not in every run of A
    assert "| B | 1 | 6 | 6: +120.0, 7: +130.0 |" in out
    assert (tmp_path / "fig.png").stat().st_size > 0
    assert start_of_learning.first_above(json.loads(Path(a).read_text()), 200.0) == [None, 9]


def test_other_episodes_and_bad_arguments_are_refused(tmp_path):
    a = _curve(tmp_path / "a.json", [{6: 50.0}])
    b = _curve(tmp_path / "b.json", [{6: 50.0}], dict(EPISODES, seed=1))
    with pytest.raises(SystemExit, match="different episodes"):
        start_of_learning.main([f"A={a}", f"B={b}", "--out", str(tmp_path / "fig.png")])
    with pytest.raises(SystemExit, match="expected NAME=CURVE_JSON"):
        start_of_learning.main([a, "--out", str(tmp_path / "fig.png")])
