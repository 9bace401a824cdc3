"""Procedural training targets (scripts/procedural_targets.py): reproducible from their seed, loadable, within the
catalogue's sizes and geom pad (the learning arms that train on them: lab/tests/test_procedural_arm.py)."""

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from ramavt_jax import targets

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "scripts"))
import procedural_targets  # noqa: E402


@pytest.fixture(scope="module")
def models(tmp_path_factory):
    """Models 0-7 of seed 0 (two of each kind) written to a folder -> their paths."""
    return procedural_targets.write_models(tmp_path_factory.mktemp("procedural"), 8, seed=0)


def test_a_model_depends_only_on_its_seed_and_index():
    first, again = procedural_targets.procedural_target(0, 5), procedural_targets.procedural_target(0, 5)
    assert first.xml() == again.xml()
    assert first.xml() != procedural_targets.procedural_target(0, 9).xml()  # same kind, another index
    assert first.xml() != procedural_targets.procedural_target(1, 5).xml()  # another seed


def test_models_load_within_the_catalogue_sizes_and_pad(models):
    _, infos = targets.load_many(models)
    kinds = [p.stem.split("-")[1].rstrip("0123456789") for p in models]
    assert kinds == list(procedural_targets.KINDS) * 2
    low, high = procedural_targets.RADIUS_RANGE
    for path, info in zip(models, infos):
        assert low - 1e-3 <= info.bound_radius <= high + 1e-3, (path.name, info.bound_radius)
        assert 1 <= info.num_geoms <= procedural_targets.MAX_GEOMS, (path.name, info.num_geoms)
    radii = [info.bound_radius for info in infos]
    assert np.std(radii) > 0.1  # drawn, not one size
    pad = targets.load_many(targets.TRAIN_TARGETS)[0].geom_mask.shape[-1]
    assert procedural_targets.MAX_GEOMS == pad  # training on them pads no further than the catalogue does


def test_one_winged_satellites_are_centred_off_their_centre_of_mass(tmp_path):
    """The point of the 'sat' kind: a light wing on one side moves the geometry's centre well off the centre of mass
    (the loader puts the centre of mass at the origin)."""
    offsets = []
    for index in range(0, 80, len(procedural_targets.KINDS)):
        t = procedural_targets.procedural_target(0, index)
        wings = {name[len("wing_")] for _, name, *_ in t.geoms if name.startswith("wing_")}
        if wings == {"p"} or wings == {"m"}:
            arrays, info = targets.load_numpy(_written(t, tmp_path))
            mask = arrays["geom_mask"] > 0
            centre = np.average(arrays["geom_pos"][mask], axis=0, weights=arrays["geom_rbound"][mask])
            offsets.append(np.linalg.norm(centre) / info.bound_radius)
    assert len(offsets) >= 5
    assert min(offsets) > 0.15  # in bounding radii; two-winged ones: 0.02-0.25


def _written(target, folder: Path) -> Path:
    path = folder / f"{target.name}.xml"
    path.write_text(target.xml())
    return path


def test_command_line_refuses_no_models(tmp_path):
    result = _script("--count", "0", "--out", str(tmp_path))
    assert result.returncode != 0 and "--count must be at least 1" in result.stderr
    result = _script("--list-train", str(tmp_path))
    assert result.returncode != 0 and "no .xml models in" in result.stderr


def test_too_many_geoms_is_an_error(monkeypatch):
    monkeypatch.setattr(procedural_targets, "MAX_GEOMS", 2)
    with pytest.raises(ValueError, match="more than MAX_GEOMS"):
        procedural_targets.procedural_target(0, 0)


def _script(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, str(ROOT / "scripts" / "procedural_targets.py"), *args], capture_output=True, text=True
    )


def test_the_shape_grounds_in_the_package_are_the_generators_and_span_the_sizes(tmp_path):
    """'val-shapes' and 'test-shapes' are `ground_target`'s models of their seeds, byte for byte, and cover what a user
    may bring: six of each kind, bounding radii from under 0.5 m to over 8 m, densities off the catalogue's values."""
    for split_name, seed in procedural_targets.GROUND_SEEDS.items():
        names = targets.split(split_name)
        assert len(names) == procedural_targets.GROUND_COUNT and seed != 0  # seed 0: the training models'
        for index, name in enumerate(names):
            t = procedural_targets.ground_target(seed, index)
            assert name == t.name and (targets.SHAPES_DIR / f"{name}.xml").read_text() == t.xml()
        _, infos = targets.load_many(names)
        radii = np.array([info.bound_radius for info in infos])
        low, high = procedural_targets.GROUND_RADIUS_RANGE
        assert radii.min() >= low - 1e-3 and radii.max() <= high + 1e-3
        assert (radii < 0.5).sum() >= 3 and (radii > 8).sum() >= 3
        kinds = [n.split("-")[1].rstrip("0123456789") for n in names]
        assert kinds == list(procedural_targets.KINDS) * (len(names) // len(procedural_targets.KINDS))
    assert not set(targets.VAL_SHAPE_TARGETS) & set(targets.TEST_SHAPE_TARGETS)


def test_a_ground_model_spreads_densities_and_keeps_the_shape():
    plain, ground = procedural_targets.procedural_target(1001, 16), procedural_targets.ground_target(1001, 16)
    assert [g[:3] for g in plain.geoms] == [g[:3] for g in ground.geoms]  # kind, name, colour
    ratios = np.array([g[3] / p[3] for g, p in zip(ground.geoms, plain.geoms)])
    spread = procedural_targets.GROUND_DENSITY_SPREAD
    assert np.all((ratios >= 1 / spread) & (ratios <= spread)) and np.ptp(np.log(ratios)) > 0.3
