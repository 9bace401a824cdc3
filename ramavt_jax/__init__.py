"""ramavt_jax: vectorised JAX active visual tracking of tumbling space objects (a RAMAVT successor).

The names most programs need, importable from the top::

    import ramavt_jax as rv
    tracking_env = rv.TrackingEnv(rv.EnvConfig(camera=rv.CameraConfig(resolution=32), obs_mode="depth"))
    train = rv.make_train(rv.preset("smoke"))              # the jitted trainer of a preset
    summary = rv.train_and_evaluate(rv.preset("smoke"), "runs/smoke")
    agent = rv.load_pretrained()                           # the shipped agent
    stats, _ = rv.run_episodes(tracking_env, agent.policy, tracking_env.eval_params(), key, 8)

Each name is imported on first use (PEP 562), so ``import ramavt_jax`` stays cheap and the package's layers (see
pyproject.toml's import contracts) keep importing each other directly. The modules themselves are the functional
API: ``from ramavt_jax import env, render, network, targets, dynamics``.
"""

from __future__ import annotations

import importlib

__version__ = "0.4.0"

# name -> (module, attribute)
_EXPORTS = {
    "TrackingEnv": ("ramavt_jax.env", "TrackingEnv"),
    "EnvConfig": ("ramavt_jax.env_config", "EnvConfig"),
    "EnvParams": ("ramavt_jax.env_config", "EnvParams"),
    "CameraConfig": ("ramavt_jax.render", "CameraConfig"),
    "TrainConfig": ("ramavt_jax.train_config", "TrainConfig"),
    "PRESETS": ("ramavt_jax.presets", "PRESETS"),
    "preset": ("ramavt_jax.presets", "preset"),
    "make_train": ("ramavt_jax.train", "make_train"),
    "train_and_evaluate": ("ramavt_jax.experiment", "train_and_evaluate"),
    "load_pretrained": ("ramavt_jax.evaluation.pretrained", "load"),
    "run_episodes": ("ramavt_jax.evaluation.rollouts", "run_episodes"),
    "summarise": ("ramavt_jax.evaluation.rollouts", "summarise"),
}

__all__ = ["__version__", *_EXPORTS]


def __getattr__(name: str):
    if name not in _EXPORTS:
        raise AttributeError(f"module 'ramavt_jax' has no attribute {name!r}")
    module, attribute = _EXPORTS[name]
    value = getattr(importlib.import_module(module), attribute)
    globals()[name] = value  # later lookups skip this function
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_EXPORTS))
