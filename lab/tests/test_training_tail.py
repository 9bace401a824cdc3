"""lab/training_tail.py: per-seed means of training metrics over a run's last chunks."""

import json
import math

import pytest

from lab import training_tail  # noqa: E402


def test_the_tail_mean_skips_earlier_chunks_and_missing_values():
    records = [
        {"chunk": 1, "episode_return": 1000.0},
        {"chunk": 2, "episode_return": 10.0},
        {"chunk": 3, "episode_return": 20.0, "expert_agreement": 0.5},
        {"chunk": 4, "episode_return": math.nan, "expert_agreement": None},
    ]
    means = training_tail.tail_means(records, ("episode_return", "expert_agreement", "aux_loss"), from_chunk=2)
    assert means["episode_return"] == pytest.approx(15.0) and means["expert_agreement"] == pytest.approx(0.5)
    assert math.isnan(means["aux_loss"])


def test_each_run_folder_gets_its_row(tmp_path, capsys):
    for seed, ret in ((0, 100.0), (1, 300.0)):
        folder = tmp_path / f"seed_{seed}"
        folder.mkdir()
        lines = [json.dumps({"chunk": c, "episode_return": ret * c, "expert_agreement": 0.1 * c}) for c in (1, 2, 3)]
        (folder / "metrics.jsonl").write_text("\n".join(lines) + "\n")
    rows = training_tail.main([str(tmp_path / "seed_0"), str(tmp_path / "seed_1"), "--from-chunk", "2"])
    assert rows[str(tmp_path / "seed_1")]["episode_return"] == pytest.approx(750.0)
    assert "episode_return: 250.000 to 750.000 over 2 run(s)" in capsys.readouterr().out
    with pytest.raises(SystemExit, match="no metrics.jsonl records"):
        training_tail.main([str(tmp_path / "missing")])
