"""lab/arm_records.py: the tidy table holds every figure RESULTS.md quotes from the lab's and the test split's
evaluations, and it is rebuilt from result files exactly."""

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from lab import arm_records

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def rows():
    return arm_records.load()


@pytest.mark.parametrize(
    ("record", "arm", "setting", "seeds", "aer"),
    [
        ("test_quick_margin", "expert_margin", "none", 5, 655.8),  # RESULTS.md: the quick preset on the test split
        ("test_long_margin", "long_margin", "none", 5, 662.8),  # the long preset
        ("test_robust", "perturb_05_margin", "all", 5, 372.4),  # the robust preset under all three perturbations
        ("val/arms/ten-seeds/margin_10", "margin_10", "none", 10, 607.0),  # expert-margin on validation
        ("val/arms/ten-seeds/avg1536k_10", "avg1536k_10", "none", 10, 582.7),  # the same without the labels
    ],
)
def test_the_table_reproduces_the_published_means(rows, record, arm, setting, seeds, aer):
    per_seed = arm_records.seed_means(rows, record, arm, setting)
    assert len(per_seed) == seeds
    assert np.mean(per_seed) == pytest.approx(aer, abs=0.05)


def test_rebuilding_from_a_result_file_gives_its_rows(tmp_path):
    """The committed test-split evaluation, rebuilt: one row per policy, setting and target (and 'all'), the
    figures as the file holds them."""
    shutil.copytree(ROOT / "results" / "test_shipped", tmp_path / "test_shipped")
    built = arm_records.build(tmp_path)
    data = json.loads((ROOT / "results" / "test_shipped" / "results.json").read_text())
    (row,) = data["rows"]
    assert len(built) == sum(1 + len(s["per_target"]) for s in row["settings"].values())
    overall = arm_records.select(built, setting="none", target="all")[0]
    assert overall["split"] == "test" and overall["policy"] == "pretrained:ramavt_depth"
    assert float(overall["aer"]) == pytest.approx(row["settings"]["none"]["overall"]["return_mean"], rel=1e-5)
    arm_records.write(built, tmp_path / "t.csv.gz")
    assert arm_records.load(tmp_path / "t.csv.gz") == built
    assert arm_records.select(built, setting="nothing") == []  # a selection can come back empty
