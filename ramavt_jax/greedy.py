"""The greedy policy of a trained Q-network, as a ``baselines.Policy`` (one env; vmap it over envs)."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
from flax import struct

from ramavt_jax import env as env_lib
from ramavt_jax.baselines import Policy
from ramavt_jax.network import NetworkConfig, RecurrentState, initial_state, make_network, record_action
from ramavt_jax.network_config import TRUE_STATE_SIZE
from ramavt_jax.network_inputs import hit_mask
from ramavt_jax.render import CameraConfig, camera_rays

__all__ = [
    "BLIND_SEARCHES",
    "GreedyState",
    "greedy_policy",
    "stack_params",
    "GreedyPolicyOf",
    "unbatch_state",
    "batch_state",
    "standoff_signal",
    "true_tracking_state",
    "visible_tracking_state",
    "tracking_state_of",
    "privileged_of",
    "privileged_size",
    "surface_centroid",
]


def standoff_signal(network: NetworkConfig, env_state: env_lib.EnvState, env_params: env_lib.EnvParams):
    """[] What a network that reads the stand-off takes from one env's state (NetworkConfig.reads_standoff): its
    scale k (standoff_input) or its command gain (command_gain_input, env.command_gain); None for other networks."""
    if network.standoff_input:
        return env_state.scale
    if network.command_gain_input:
        return env_lib.command_gain(env_state, env_params)
    return None


def true_tracking_state(env_state: env_lib.EnvState, env_params: env_lib.EnvParams) -> jax.Array:
    """[6] One env's true tracking state in stand-off distances (metres / (k * desired_pos[2])): where the target
    centre is minus where it should be (camera frame), then the target's velocity relative to the chaser (camera
    frame, per second). The auxiliary loss's label (its first aux_outputs entries) and a state_input network's
    input."""
    p = env_params
    error = (env_lib.relative_position(env_state) / env_state.scale - p.desired_pos) / p.desired_pos[2]
    velocity = env_lib.HILL_FROM_CAM.T @ (env_state.target_vel - env_state.chaser_vel)
    return jnp.concatenate([error, velocity / env_state.scale / p.desired_pos[2]])


def surface_centroid(depth: jax.Array, camera: CameraConfig) -> tuple[jax.Array, jax.Array]:
    """Of a z-depth image [H, W] (0 where nothing is hit): ([3] the mean camera-frame point of its hit pixels, each
    back-projected along its ray at its depth, in the depth's units; [] how many there are)."""
    hit = depth > 0
    count = jnp.sum(hit)
    points = camera_rays(camera) * depth[..., None]  # [H, W, 3]: ray (x, y, 1) times z depth
    return jnp.sum(jnp.where(hit[..., None], points, 0.0), axis=(0, 1)) / jnp.maximum(count, 1), count


def visible_tracking_state(
    env_state: env_lib.EnvState, env_params: env_lib.EnvParams, camera: CameraConfig, image_only: bool = False
) -> jax.Array:
    """[6] true_tracking_state with the error measured to the centroid of the target's visible surface instead of
    its centre of mass: the mean camera-frame point of the newest frame's target pixels ('depth' or 'rgbd'
    observations: depth / far last; a target at stand-off scale k is drawn at 1 / k, so the frame is already in
    stand-off units). On a frame without a target pixel the true state: a diagnostic, what a perfect reading of the
    visible surface gives (NetworkConfig.state_input_point 'visible'). ``image_only``: zeros there and for the
    velocity, so that nothing but the frame and the desired point is read (point 'image'). The newest frame is
    read sharp: under the blur perturbation the observation averages it with earlier ones, and the Gaussian or
    motion blur of EnvParams would move depth into background pixels; neither is applied here."""
    if env_state.frames.shape[-1] not in (1, 4):
        raise ValueError(
            f"visible_tracking_state needs a depth channel ('depth' or 'rgbd' observations), got "
            f"{env_state.frames.shape[-1]} channels"
        )
    centroid, count = surface_centroid(env_state.frames[-1][..., -1] * camera.far, camera)  # m / k
    error = (centroid - env_params.desired_pos) / env_params.desired_pos[2]
    if image_only:
        return jnp.concatenate([jnp.where(count > 0, error, 0.0), jnp.zeros(3, error.dtype)])
    true = true_tracking_state(env_state, env_params)
    return jnp.where(count > 0, true.at[:3].set(error), true)


def tracking_state_of(network: NetworkConfig, camera: CameraConfig | None = None):
    """The function (env_state, env_params) -> [6] a state_input network reads (NetworkConfig.state_input_point):
    true_tracking_state, or visible_tracking_state on ``camera`` (the env's; refused if missing)."""
    point = network.state_input_point
    if point == "centre":
        return true_tracking_state
    if camera is None:
        raise ValueError(f"a state_input_point {point!r} network needs the env's camera (greedy_policy(camera=...))")
    return lambda env_state, env_params: visible_tracking_state(env_state, env_params, camera, point == "image")


def privileged_of(network: NetworkConfig, camera: CameraConfig | None = None):
    """The function (env_state, env_params) -> [K] a trainer stores per obs (replay.Transition.privileged): the true
    state [6], whose first entries are the auxiliary head's label; for a state_input_point other than 'centre' the
    network's input follows it ([12]: the label stays the centre's, the input is the last six)."""
    if network.state_input_point == "centre":
        return true_tracking_state
    read = tracking_state_of(network, camera)
    return lambda s, p: jnp.concatenate([true_tracking_state(s, p), read(s, p)])


def privileged_size(network: NetworkConfig, aux_weight: float) -> int:
    """K, the entries privileged_of gives that a trainer keeps: all for a state_input network, else the auxiliary
    head's label (its outputs; 0 without the loss: nothing kept)."""
    if network.state_input:
        return TRUE_STATE_SIZE * (1 if network.state_input_point == "centre" else 2)
    return network.aux_outputs if aux_weight else 0


def unbatch_state(s: RecurrentState) -> RecurrentState:
    """A batch-of-one state without its batch axis: h, c, prev_action, exposure [layers, 1, ...] ->
    [layers, ...], frames [1, ...] -> [...]."""
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
    camera: CameraConfig | None = None,
) -> Policy:
    """A ``baselines.Policy`` acting greedily with a trained Q-network (per env; evaluate.run_episodes vmaps it). A
    state_input network also reads env_state: the simulator's state (a diagnostic, not a deployable tracker), or with
    state_input_point 'image' the newest frame (env_state.frames) and the desired point alone.

    ``search`` is what it commands while no frame of the episode has shown a target pixel: 'learned' (the Q-net's
    greedy action, as everywhere else) or 'retreat' (back along the camera axis, which shrinks the bearing of a
    target in any direction). A blank image shows nothing to choose by, so a fixed search gives up only what a
    policy may have learned of where targets tend to start; the network still sees every frame and is told the
    command flown.

    ``members`` > 0: ``params`` holds that many parameter sets of this one network stacked on a leading axis
    (:func:`stack_params`, e.g. the seeds of a sweep). Each member keeps its own memory and is told the command
    flown; the policy takes the argmax of the members' mean output (Q, or a policy head's logits)."""
    if search not in BLIND_SEARCHES:
        raise ValueError(f"search must be one of {BLIND_SEARCHES}, got {search!r}")
    leading = {leaf.shape[0] for leaf in jax.tree.leaves(params)} if members else set()
    if members < 0 or (members and leading != {members}):
        raise ValueError(
            f"members must be 0 (one network) or the leading axis of every stacked parameter, got "
            f"{members} for leading axes {sorted(leading)}"
        )
    net = make_network(network)
    state_of = tracking_state_of(network, camera) if network.state_input else None

    def forward(member_params, net_state, first, obs, standoff, true_state):  # one network, one step: q [A], state
        q, new = net.apply(
            {"params": member_params},
            obs[None, None],
            first[None, None],
            batch_state(net_state),
            standoff=standoff,
            true_state=true_state,
        )
        return q[0, 0], new

    def init(key):
        s = unbatch_state(initial_state(network, 1, obs_shape))
        if members:
            s = jax.tree.map(lambda x: jnp.broadcast_to(x, (members, *x.shape)), s)
        return GreedyState(net_state=s, first=jnp.ones((), bool), seen=jnp.zeros((), bool))

    def act(key, pstate: GreedyState, obs, env_state, env_params):
        signal = standoff_signal(network, env_state, env_params)
        standoff = None if signal is None else signal[None, None]  # [1, 1]
        true_state = state_of(env_state, env_params)[None, None] if network.state_input else None
        inputs = (pstate.first, obs, standoff, true_state)
        if members:
            q, new = jax.vmap(forward, in_axes=(0, 0) + (None,) * 4)(params, pstate.net_state, *inputs)
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
    camera: CameraConfig | None = None  # the env's (needed by a state_input_point other than 'centre')

    def __call__(self, params) -> Policy:
        return greedy_policy(self.network, params, tuple(self.obs_shape), self.name, camera=self.camera)
