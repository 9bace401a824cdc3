"""The dict form of the config dataclasses (config.json, a checkpoint's metadata) read back.

`build` makes a (nested) config dataclass of its dict; `without_retired_fields` drops the fields of earlier
versions (`RETIRED_FIELDS`) that hold their old values and refuses those that do not. ``TrainConfig.from_dict``
uses both; the run folder's config check (``training.run_folder``) the latter.
"""

from __future__ import annotations

import dataclasses
import typing

__all__ = ["RETIRED_FIELDS", "build", "without_retired_fields"]


def build(cls, data: dict):
    """A (nested) config dataclass from its dict form: lists become tuples; missing fields take their defaults."""
    hints = typing.get_type_hints(cls)
    kwargs = {}
    for f in dataclasses.fields(cls):
        if f.name in data:
            value, sub = data[f.name], hints.get(f.name)
            kwargs[f.name] = (
                build(sub, value) if dataclasses.is_dataclass(sub) and isinstance(value, dict) else _tuplify(value)
            )
    return cls(**kwargs)


# Fields of earlier versions, removed with the research arms that used them (their record: lab/experiments.md), each
# with the value it held in every run that did not use its arm: a config.json (a run folder's, a checkpoint's, a
# shipped agent's) that holds one at that value reads as this version's config; at another value it is refused.
RETIRED_FIELDS = {
    "acting.eps_ladder": 0.0,
    "acting.teacher_envs": 0,
    "network.depth_centre": 0.0,
    "network.depth_gain": 1.0,
    "network.silhouette_stats": False,
    "network.standoff_input": False,
    "network.command_gain_input": False,
    "network.dueling": False,
    "network.quantiles": 0,
    "network.policy_head": False,
    "network.dense_norm": False,
    "network.state_input": False,
    "network.state_input_gain": 1.0,
    "network.state_input_entries": (0, 1, 2, 3, 4, 5),
    "network.state_input_point": "centre",
    "network.frame_difference": False,
    "network.exposure_rate": 0.0,
    "learner.lr_final": None,
    "learner.adam_eps": 1e-4,
    "learner.td_lambda": None,
    "learner.value_rescale": False,
    "learner.huber_delta": None,
    "learner.quantile_kappa": 0.05,
    "learner.advantage_alpha": 0.0,
    "learner.command_cost": 0.0,
    "learner.expert_margin": 0.05,
    "learner.policy_weight": 1.0,
    "learner.polyak_tau_start": None,
    "learner.polyak_tau_decay": (1000, 2000),
}


def without_retired_fields(data: dict) -> dict:
    """A config dict (``TrainConfig.to_dict``'s form) without the RETIRED_FIELDS it holds at their old values;
    ValueError (one line) for one at another value: the run used an arm this version no longer has."""
    data = dict(data)
    for name, unused in RETIRED_FIELDS.items():
        group, field = name.split(".")
        if not isinstance(data.get(group), dict) or field not in data[group]:
            continue
        value = data[group][field]
        if _tuplify(value) != unused or isinstance(value, bool) != isinstance(unused, bool):
            raise ValueError(
                f"TrainConfig: {name} = {value!r} belongs to a research arm this version no longer has (only "
                f"{unused!r}, its value when unused, is read); the run needs the version it was trained with"
            )
        data[group] = {k: v for k, v in data[group].items() if k != field}
    return data


_tuplify = lambda x: tuple(_tuplify(v) for v in x) if isinstance(x, list) else x  # noqa: E731 (JSON lists)
