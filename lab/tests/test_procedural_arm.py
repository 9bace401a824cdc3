"""The lab's procedural-model arms (scripts/procedural_targets.py writes the models): each changes only the training
targets, and the reproduce command lists them in the arm's order."""

import dataclasses
import subprocess
import sys
from pathlib import Path

import pytest

from lab import learning_arms
from ramavt_jax import targets

ROOT = Path(__file__).resolve().parents[2]


def _script(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, str(ROOT / "scripts" / "procedural_targets.py"), *args], capture_output=True, text=True
    )


@pytest.mark.parametrize(
    "arm, reference",
    [("procedural-48", "avg-1536k"), ("size-procedural-48", "size-1536k"), ("procedural-48-margin", "expert-margin")],
)
def test_the_arm_adds_the_models_to_the_training_targets_only(arm, reference, tmp_path, monkeypatch):
    monkeypatch.setattr(learning_arms, "PROCEDURAL_DIR", tmp_path)
    arm, reference = learning_arms.arm_config(arm), learning_arms.arm_config(reference)
    assert arm.env.targets[: len(targets.TRAIN_TARGETS)] == targets.TRAIN_TARGETS
    added = arm.env.targets[len(targets.TRAIN_TARGETS) :]
    assert len(added) == 48 and all(Path(p).parent == tmp_path and Path(p).is_file() for p in added)
    assert dataclasses.replace(arm, env=dataclasses.replace(arm.env, targets=targets.TRAIN_TARGETS)) == reference


def test_the_listed_targets_are_the_arms_in_its_order(tmp_path, monkeypatch):
    """What the reproduce command passes to `ramavt train --env.targets` (--list-train) is the arm's list, in the
    same order (an episode draws its target by list index); a file of another name comes last."""
    monkeypatch.setattr(learning_arms, "PROCEDURAL_DIR", tmp_path)
    arm_targets = list(learning_arms.arm_config("procedural-48").env.targets)
    (tmp_path / "a-user-model.xml").write_text((tmp_path / "Gen0-sat000.xml").read_text())
    listed = _script("--list-train", str(tmp_path))
    assert listed.returncode == 0, listed.stderr
    assert listed.stdout.split() == [*arm_targets, str(tmp_path / "a-user-model.xml")]
