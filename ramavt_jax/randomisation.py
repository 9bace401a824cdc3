"""Domain randomisation (training): an episode's target size (`size_factor`), shape (`stretch`) and centre offset
(`shift`), and which of the configured perturbations the episode has (`perturbed`).

Each function takes its own key (env.TrackingEnv.initial_state splits one per draw from the episode's key), so the
episode's other draws (target, pose, velocities) do not depend on these, and with the defaults (no resizing, no
stretch, no offset, every configured perturbation on) the target and its perturbations are exactly as configured.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from ramavt_jax import targets as targets_lib
from ramavt_jax.env_config import EnvParams


def size_factor(key: jax.Array, params: EnvParams) -> jax.Array:
    """[] Factor on the episode's target geometry: in a share size_scale_prob of the episodes log-uniform in
    [size_scale_min, size_scale_max], else 1 (exactly 1.0 by default). Mass and inertia are kept: torque-free
    rotation does not change under a uniform scale of the inertia (Euler's equations are homogeneous in it)."""
    k_factor, k_on = jax.random.split(key)
    low, high = jnp.log(params.size_scale_min), jnp.log(params.size_scale_max)
    factor = jnp.exp(jax.random.uniform(k_factor, (), minval=low, maxval=high))
    resized = jax.random.uniform(k_on, ()) < params.size_scale_prob
    return jnp.where(resized, factor, 1.0)


def stretch_factors(key: jax.Array, params: EnvParams) -> tuple[jax.Array, jax.Array]:
    """([3] factors along the principal axes, [] whether this episode is stretched): log factors uniform in
    [-ln stretch_max, ln stretch_max], centred so that their product is 1, in a share stretch_prob of the
    episodes (never when stretch_max is 1)."""
    k_factors, k_on = jax.random.split(key)
    u = jax.random.uniform(k_factors, (3,), minval=-1.0, maxval=1.0)
    factors = jnp.exp((u - jnp.mean(u)) * jnp.log(params.stretch_max))
    drawn = jax.random.uniform(k_on, ()) < params.stretch_prob
    return factors, drawn & (params.stretch_max > 1.0)


def _either(on: jax.Array, drawn: targets_lib.TargetModel, own: targets_lib.TargetModel) -> targets_lib.TargetModel:
    """``drawn`` where ``on`` (a traced bool), else exactly ``own``."""
    return jax.tree.map(lambda d, o: jnp.where(on, d, o), drawn, own)


def stretch(key: jax.Array, target: targets_lib.TargetModel, params: EnvParams) -> targets_lib.TargetModel:
    """The episode's target, stretched (targets.stretched) when stretch_factors says so, else exactly itself."""
    factors, on = stretch_factors(key, params)
    return _either(on, targets_lib.stretched(target, factors), target)


def centre_offset(key: jax.Array, radius: jax.Array, params: EnvParams) -> tuple[jax.Array, jax.Array]:
    """([3] body-frame offset of the geometry, m, uniform in the ball of radius offset_max * radius, [] whether this
    episode has it): in a share offset_prob of the episodes, never when offset_max is 0."""
    k_direction, k_length, k_on = jax.random.split(key, 3)
    direction = jax.random.normal(k_direction, (3,))
    direction = direction / jnp.maximum(jnp.linalg.norm(direction), 1e-12)
    length = params.offset_max * radius * jax.random.uniform(k_length, ()) ** (1 / 3)
    drawn = jax.random.uniform(k_on, ()) < params.offset_prob
    return direction * length, drawn & (params.offset_max > 0.0)


def shift(key: jax.Array, target: targets_lib.TargetModel, params: EnvParams) -> targets_lib.TargetModel:
    """The episode's target with its geometry off its centre (targets.shifted) when centre_offset says so, else
    exactly itself."""
    offset, on = centre_offset(key, target.bound_radius, params)
    return _either(on, targets_lib.shifted(target, offset), target)


def perturbed(key: jax.Array, params: EnvParams) -> jax.Array:
    """[3] float, 1.0 where the episode has the perturbation, else 0.0: actuator noise, time delay, frame-averaging
    blur, each on with probability perturb_prob (always at the default 1). The env applies a configured
    perturbation where its flag is 1, so one that is not configured stays off either way."""
    draws = jax.random.uniform(key, (3,))
    return (draws < params.perturb_prob).astype(jnp.float32)
