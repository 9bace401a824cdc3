"""lab/merge_results.py: results of one arm's seed groups become one arm of all their seeds, and results of other
episodes or repeated seeds are refused."""

import json

import pytest

from lab import merge_results  # noqa: E402
from ramavt_jax.evaluation import seeds  # noqa: E402


def _result(folder: str, training_seeds, aer: float, seed: int = 0, eval_params=None) -> dict:
    rows = [
        {
            "name": f"{folder}/seed_{s}",
            "kind": "checkpoint",
            "info": {"run_dir": f"runs/{folder}/seed_{s}", "seed": s},
            "settings": {"none": {"per_target": {"A": {"return_mean": aer + s}}, "overall": {"return_mean": aer + s}}},
        }
        for s in training_seeds
    ]
    rows.append({"name": "depth", "kind": "baseline", "info": {}, "settings": {}})
    settings = {
        "seed": seed,
        "episodes_per_target": 2,
        "targets": ["A"],
        "max_steps": 10,
        "eval_params": eval_params or {"dist_weight": 1.0},
    }
    return {"settings": settings, "rows": rows, "arms": {"stale": 1}, "command": f"ramavt eval {folder}"}


def test_seed_groups_become_one_arm(tmp_path):
    first, second = tmp_path / "a.json", tmp_path / "b.json"
    first.write_text(json.dumps(_result("x", [0, 1], 100.0)))
    second.write_text(json.dumps(_result("x_s5", [5, 6], 200.0, eval_params={"dist_weight": 1.0, "new_field": 0.0})))
    out = tmp_path / "merged.json"
    merge_results.main([str(out), "ten", str(first), str(second)])
    merged = json.loads(out.read_text())
    assert "arms" not in merged and merged["merged_from"] == ["ramavt eval x", "ramavt eval x_s5"]
    grouped = seeds.arms(merged)
    assert list(grouped) == ["ten (seeds)"]  # the baseline row is dropped, the four seeds are one arm
    assert [r["overall"]["return_mean"] for r in grouped["ten (seeds)"]] == [100.0, 101.0, 205.0, 206.0]


def test_other_episodes_and_repeated_seeds_are_refused(tmp_path):
    results = [_result("x", [0], 1.0), _result("y", [1], 1.0, seed=1)]
    with pytest.raises(SystemExit, match="different episodes or rules"):
        merge_results.merge("z", results)
    with pytest.raises(SystemExit, match="different episodes or rules"):
        merge_results.merge("z", [_result("x", [0], 1.0), _result("y", [1], 1.0, eval_params={"dist_weight": 0.5})])
    with pytest.raises(SystemExit, match="training seed 0 is in more than one result"):
        merge_results.merge("z", [_result("x", [0], 1.0), _result("y", [0], 1.0)])


def test_one_arm_of_a_result_of_several(tmp_path):
    """RESULTS_JSON:ARM takes only that run folder's rows of a result that evaluated several arms' runs."""
    both = _result("x", [0, 1], 100.0)
    both["rows"] += _result("y", [0, 1], 300.0)["rows"]
    (tmp_path / "both.json").write_text(json.dumps(both))
    (tmp_path / "more.json").write_text(json.dumps(_result("y_s5", [5], 400.0)))
    out = tmp_path / "merged.json"
    merge_results.main([str(out), "y3", f"{tmp_path / 'both.json'}:y", str(tmp_path / "more.json")])
    grouped = seeds.arms(json.loads(out.read_text()))
    assert [r["overall"]["return_mean"] for r in grouped["y3 (seeds)"]] == [300.0, 301.0, 405.0]
    with pytest.raises(SystemExit, match="no checkpoint rows of 'z'"):
        merge_results.read(f"{tmp_path / 'both.json'}:z")
