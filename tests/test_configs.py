"""Every field of NetworkConfig and LearnerConfig earns its place: a preset sets it away from its default, or an
allowlist below names the paper variant, ablation or documented feature that uses it. A field that neither uses is a
research arm's and belongs in lab/ (through the trainer's extension points, docs/extending.md). Also: config.json
files of earlier versions, which hold the fields since retired (config_dicts.RETIRED_FIELDS), still load."""

import dataclasses
import json

import pytest

from ramavt_jax import presets
from ramavt_jax.config_dicts import RETIRED_FIELDS, without_retired_fields
from ramavt_jax.network_config import NetworkConfig
from ramavt_jax.train_config import LearnerConfig, TrainConfig
from ramavt_jax.training import run_folder

# Fields no preset sets away from its default, each with what uses it.
ALLOWED = {
    NetworkConfig: {
        # The env's action count (env.NUM_ACTIONS), checked against it by TrainConfig: fixed by the task.
        "num_actions": "the task (env.NUM_ACTIONS)",
        # The paper's block order conv -> SE -> norm -> pool -> ReLU (False); network.py's docstring.
        "pool_first": "the paper's block order (network.py, docs/design.md)",
        # The paper's network variants and Table III's ablation (RESULTS.md): batch norm, none, and DRLAVT's
        # stacked frames and dense layers ('drlavt', Table I).
        "norm": "the paper's ablation (network.py's docstring)",
        "drlavt_dense": "variant 'drlavt' (RESULTS.md, Table I)",
        "frame_stack": "variant 'drlavt' (RESULTS.md, Table I)",
        # Documented features for speed: the same parameters, another conv, another precision.
        "conv_impl": "docs/design.md, Speed",
        "dtype": "docs/design.md, Speed",
    },
    LearnerConfig: {
        # The Polyak rate of target_update 'polyak' (the quick preset sets it, at the default value).
        "polyak_tau": "the quick preset (at the default value) and the paper's target update",
        # Table III's '+Augment' row (RESULTS.md): cutout on the sampled windows.
        "augment": "RESULTS.md, Table III ('+Augment')",
        "augment_config": "RESULTS.md, Table III ('+Augment')",
    },
}


def unused_fields(cls, configs, allowed: dict[str, str]) -> list[str]:
    """The fields of dataclass ``cls`` that no config in ``configs`` (instances of ``cls``) sets away from the
    default and that ``allowed`` does not name."""
    default = cls()
    used = {f.name for c in configs for f in dataclasses.fields(cls) if getattr(c, f.name) != getattr(default, f.name)}
    return [f.name for f in dataclasses.fields(cls) if f.name not in used and f.name not in allowed]


def _group(cls) -> str:
    return {NetworkConfig: "network", LearnerConfig: "learner"}[cls]


@pytest.mark.parametrize("cls", [NetworkConfig, LearnerConfig])
def test_every_field_is_set_by_a_preset_or_used_by_a_named_variant_or_feature(cls):
    configs = [getattr(presets.preset(name), _group(cls)) for name in presets.PRESETS]
    assert unused_fields(cls, configs, ALLOWED[cls]) == []
    # and the allowlist names only fields that exist and no preset already sets
    names = {f.name for f in dataclasses.fields(cls)}
    assert set(ALLOWED[cls]) <= names
    assert not set(ALLOWED[cls]) - set(unused_fields(cls, configs, {})), "an allowlisted field is set by a preset"


def test_a_field_nothing_uses_is_caught():
    """The check can fail: NetworkConfig with a made-up switch that no preset sets and no entry names."""

    @dataclasses.dataclass(frozen=True)
    class WithArm(NetworkConfig):
        research_switch: bool = False

    configs = [WithArm(**dataclasses.asdict(presets.preset(name).network)) for name in presets.PRESETS]
    assert unused_fields(WithArm, configs, ALLOWED[NetworkConfig]) == ["research_switch"]
    assert unused_fields(WithArm, configs + [WithArm(research_switch=True)], ALLOWED[NetworkConfig]) == []


# ------------------------------------------------------------------------------------------ retired fields
def _with_retired(config: dict, **values) -> dict:
    """A config dict (to_dict's form) holding every retired field, at its old default unless ``values`` says."""
    out = json.loads(json.dumps(config))
    for name, unused in RETIRED_FIELDS.items():
        group, field = name.split(".")
        value = values.get(field, unused)
        out[group][field] = list(value) if isinstance(value, tuple) else value
    return out


def test_a_config_with_the_retired_fields_at_their_old_values_reads_as_this_versions():
    config = presets.preset("quick")
    assert TrainConfig.from_dict(_with_retired(config.to_dict())) == config
    assert without_retired_fields(_with_retired(config.to_dict())) == json.loads(json.dumps(config.to_dict()))


@pytest.mark.parametrize("field, value", [("dueling", True), ("td_lambda", 0.9), ("teacher_envs", 8)])
def test_a_retired_field_at_another_value_is_refused_in_one_line(field, value, tmp_path):
    """A run that used a retired arm (here a dueling head, lambda-returns, demonstration envs) is refused, by
    from_dict and by a run folder's config check, in one line naming the field."""
    data = _with_retired(presets.preset("smoke").to_dict(), **{field: value})
    with pytest.raises(ValueError, match=rf"\.{field} = {value!r} belongs to a research arm") as e:
        TrainConfig.from_dict(data)
    assert "\n" not in str(e.value)
    (tmp_path / "config.json").write_text(json.dumps({"seed": 0, "config": data}))
    with pytest.raises(run_folder.RunFolderError, match=rf"config.json: TrainConfig: .*\.{field} = ") as e:
        run_folder.read_config(tmp_path)
    assert "\n" not in str(e.value)
    with pytest.raises(ValueError, match=f"{field}"):
        run_folder.config_differences(data, presets.preset("smoke").to_dict())


def test_a_run_folder_of_the_earlier_version_reads_and_resumes_as_this_versions(tmp_path):
    """config.json as the earlier version wrote it (every retired field at its old value): read_config drops them,
    and the resume check finds no difference from this version's config of the same run."""
    config = presets.preset("smoke")
    (tmp_path / "config.json").write_text(json.dumps({"seed": 3, "config": _with_retired(config.to_dict())}))
    saved = run_folder.read_config(tmp_path)
    assert TrainConfig.from_dict(saved["config"]) == config
    current = json.loads(json.dumps(config.to_dict()))
    run_folder.check_config(tmp_path, current, 3)  # no RunFolderError: the same run
    assert run_folder.config_differences(_with_retired(config.to_dict()), current) == {}
