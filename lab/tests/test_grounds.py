"""lab.grounds reads the arm a folder holds: an ensemble's row where it was evaluated with --ensemble."""

import json

from lab import grounds


def _write(folder, rows):
    folder.mkdir(parents=True)
    (folder / "results.json").write_text(json.dumps({"rows": rows}))


def test_a_folder_evaluated_with_ensemble_names_the_ensemble_else_its_seeds(tmp_path, monkeypatch):
    monkeypatch.setattr(grounds, "EVALS", tmp_path)
    seeds = [{"name": f"arm/seed_{k}", "kind": "checkpoint", "info": {"run_dir": f"runs/arm/seed_{k}"}} for k in (0, 1)]
    ensemble = {"name": "ensemble of 2: arm", "kind": "checkpoint", "info": {"ensemble_of": ["a", "b"]}}
    _write(tmp_path / "val" / "arm-ens", [*seeds, ensemble])
    _write(tmp_path / "val" / "arm", seeds)
    assert grounds._arm_key("val", "arm-ens") == "ensemble of 2: arm"
    assert grounds._arm_key("val", "arm") == "arm"
