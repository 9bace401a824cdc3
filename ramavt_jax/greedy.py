"""The greedy policy of a trained Q-network, as a ``baselines.Policy`` (one env; vmap it over envs)."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import flax.linen as nn
import jax
import jax.numpy as jnp
from flax import struct

from ramavt_jax import env as env_lib
from ramavt_jax.baselines import Policy
from ramavt_jax.network import NetworkConfig, RecurrentState, initial_state, make_network, record_action
from ramavt_jax.network_inputs import hit_mask

__all__ = [
    "BLIND_SEARCHES",
    "GreedyState",
    "greedy_policy",
    "stack_params",
    "GreedyPolicyOf",
    "unbatch_state",
    "batch_state",
]


def unbatch_state(s: RecurrentState) -> RecurrentState:
    """A batch-of-one state without its batch axis: h, c, prev_action [layers, 1, ...] -> [layers, ...], frames
    [1, ...] -> [...]."""
    return jax.tree.map(lambda x: x[:, 0], s.replace(frames=None)).replace(frames=s.frames[0])


def batch_state(s: RecurrentState) -> RecurrentState:
    """The inverse of unbatch_state."""
    return jax.tree.map(lambda x: x[:, None], s.replace(frames=None)).replace(frames=s.frames[None])


BLIND_SEARCHES = ("learned", "retreat")  # greedy_policy(search=...)


@struct.dataclass
class GreedyState:
    net_state: RecurrentState  # per env (no batch axis): h, c [layers, units], frames [K, H, W, C] (K may be 0);
    # an ensemble (greedy_policy(members=M)) has one per member, each leaf [M, ...]
    first: jax.Array  # [] bool
    seen: jax.Array  # [] bool: some frame of the episode so far has shown a target pixel (search 'retreat' only)


def greedy_policy(
    network: NetworkConfig,
    params,
    obs_shape: tuple,
    name: str = "greedy",
    search: str = "learned",
    members: int = 0,
    network_factory: Callable[[NetworkConfig], nn.Module] = make_network,
) -> Policy:
    """A ``baselines.Policy`` acting greedily with a trained Q-network (per env; evaluate.run_episodes vmaps it),
    built by ``network_factory`` (the trainer's; default network.make_network).

    ``search`` is what it commands while no frame of the episode has shown a target pixel: 'learned' (the Q-net's
    greedy action, as everywhere else) or 'retreat' (back along the camera axis, which shrinks the bearing of a
    target in any direction). A blank image shows nothing to choose by, so a fixed search gives up only what a
    policy may have learned of where targets tend to start; the network still sees every frame and is told the
    command flown.

    ``members`` > 0: ``params`` holds that many parameter sets of this one network stacked on a leading axis
    (:func:`stack_params`, e.g. the seeds of a sweep). Each member keeps its own memory and is told the command
    flown; the policy takes the argmax of the members' mean Q."""
    if search not in BLIND_SEARCHES:
        raise ValueError(f"search must be one of {BLIND_SEARCHES}, got {search!r}")
    leading = {leaf.shape[0] for leaf in jax.tree.leaves(params)} if members else set()
    if members < 0 or (members and leading != {members}):
        raise ValueError(
            f"members must be 0 (one network) or the leading axis of every stacked parameter, got "
            f"{members} for leading axes {sorted(leading)}"
        )
    net = network_factory(network)

    def forward(member_params, net_state, first, obs):  # one network, one step: q [A], state
        q, new = net.apply({"params": member_params}, obs[None, None], first[None, None], batch_state(net_state))
        return q[0, 0], new

    def init(key):
        s = unbatch_state(initial_state(network, 1, obs_shape))
        if members:
            s = jax.tree.map(lambda x: jnp.broadcast_to(x, (members, *x.shape)), s)
        return GreedyState(net_state=s, first=jnp.ones((), bool), seen=jnp.zeros((), bool))

    def act(key, pstate: GreedyState, obs, env_state, env_params):
        inputs = (pstate.first, obs)
        if members:
            q, new = jax.vmap(forward, in_axes=(0, 0, None, None))(params, pstate.net_state, *inputs)
            q = q.mean(0)
        else:
            q, new = forward(params, pstate.net_state, *inputs)
        action = jnp.argmax(q).astype(jnp.int32)
        seen = pstate.seen  # tracked for the fixed search only: one reduction over the frame a step
        if search == "retreat":
            seen = (pstate.seen & ~pstate.first) | jnp.any(hit_mask(obs[None]) > 0)
            action = jnp.where(seen, action, env_lib.RETREAT).astype(jnp.int32)
        told = lambda s: unbatch_state(record_action(s, action[None]))  # noqa: E731
        new = jax.vmap(told)(new) if members else told(new)
        return action, GreedyState(net_state=new, first=jnp.zeros((), bool), seen=seen)

    return Policy(name, init, act)


def stack_params(params_list) -> object:
    """Parameter sets of one network (a list of pytrees) stacked on a new leading axis, for greedy_policy(members=)."""
    return jax.tree.map(lambda *leaves: jnp.stack(leaves), *params_list)


@dataclasses.dataclass(frozen=True)
class GreedyPolicyOf:
    """The greedy policy of one network with its parameters left open: ``GreedyPolicyOf(network, obs_shape)(params)``
    is ``greedy_policy(network, params, obs_shape)``. Equal networks give equal (and equally hashed) objects, so an
    episode runner keyed on it (``rollouts.run_episodes(..., policy_params=params)``) compiles once for every
    parameter set of the network: the checkpoints of a run, or the seeds of a sweep."""

    network: NetworkConfig
    obs_shape: tuple
    name: str = "greedy"

    def __call__(self, params) -> Policy:
        return greedy_policy(self.network, params, tuple(self.obs_shape), self.name)
