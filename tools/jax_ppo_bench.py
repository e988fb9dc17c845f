#!/usr/bin/env python3
"""The PPO minibatch update of `rlpkg bench ppo`, written in JAX, for comparison.

Same network (actor obs-256-256-act and critic obs-256-256-1, tanh, orthogonal init, a
state-independent log-std), same loss (Gaussian log-prob, clipped surrogate, clipped value loss,
entropy bonus, advantages normalised with the sample standard deviation), same optimiser (Adam,
eps 1e-5, after scaling all gradients together to a global L2 norm of at most 1), float32, one
jitted function per minibatch. Prints one JSON object with samples/s.

    /work/venv-jax/bin/python tools/jax_ppo_bench.py --minibatch 4096 --minibatches 10
"""

import argparse
import json
import time

import jax
import jax.numpy as jnp
import numpy as np
import optax

HALF_LN_2PI = 0.5 * np.log(2.0 * np.pi)


def mlp_init(key, widths, output_gain):
    layers = []
    for i, (d_in, d_out) in enumerate(zip(widths[:-1], widths[1:])):
        key, sub = jax.random.split(key)
        gain = output_gain if i == len(widths) - 2 else np.sqrt(2.0)
        w = jax.nn.initializers.orthogonal(scale=gain)(sub, (d_in, d_out), jnp.float32)
        layers.append({"w": w, "b": jnp.zeros((d_out,), jnp.float32)})
    return layers, key


def mlp(layers, x):
    for layer in layers[:-1]:
        x = jnp.tanh(x @ layer["w"] + layer["b"])
    return x @ layers[-1]["w"] + layers[-1]["b"]


def loss_fn(params, batch, clip_ratio=0.2, value_coef=0.5, entropy_coef=0.0):
    obs, actions, old_log_probs, old_values, advantages, returns = batch
    advantages = (advantages - advantages.mean()) / (advantages.std(ddof=1) + 1e-8)
    mean = mlp(params["actor"], obs)
    log_std = params["log_std"]
    z = (actions - mean) * jnp.exp(-log_std)
    log_probs = jnp.sum(-0.5 * z * z - log_std - HALF_LN_2PI, axis=1)
    entropy = jnp.sum(log_std + 0.5 + HALF_LN_2PI)
    log_ratio = log_probs - old_log_probs
    ratio = jnp.exp(log_ratio)
    policy_loss = jnp.maximum(
        -advantages * ratio, -advantages * jnp.clip(ratio, 1 - clip_ratio, 1 + clip_ratio)
    ).mean()
    values = mlp(params["critic"], obs)[:, 0]
    unclipped = (values - returns) ** 2
    clipped = (old_values + jnp.clip(values - old_values, -clip_ratio, clip_ratio) - returns) ** 2
    value_loss = 0.5 * jnp.maximum(unclipped, clipped).mean()
    loss = policy_loss - entropy_coef * entropy + value_coef * value_loss
    approx_kl = ((ratio - 1) - log_ratio).mean()
    clip_fraction = (jnp.abs(ratio - 1) > clip_ratio).mean()
    return loss, (policy_loss, value_loss, entropy, approx_kl, clip_fraction)


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--minibatch", type=int, default=4096)
    parser.add_argument("--minibatches", type=int, default=10)
    parser.add_argument("--obs-dim", type=int, default=48)
    parser.add_argument("--action-dim", type=int, default=6)
    parser.add_argument("--hidden", type=str, default="256,256")
    args = parser.parse_args()
    hidden = [int(h) for h in args.hidden.split(",")]

    key = jax.random.PRNGKey(0)
    actor, key = mlp_init(key, [args.obs_dim, *hidden, args.action_dim], 0.01)
    critic, key = mlp_init(key, [args.obs_dim, *hidden, 1], 1.0)
    params = {"actor": actor, "critic": critic, "log_std": jnp.zeros((args.action_dim,), jnp.float32)}
    n_params = sum(x.size for x in jax.tree_util.tree_leaves(params))
    optimiser = optax.chain(optax.clip_by_global_norm(1.0), optax.adam(3e-4, eps=1e-5))
    opt_state = optimiser.init(params)

    @jax.jit
    def update(params, opt_state, batch):
        (_, diagnostics), grads = jax.value_and_grad(loss_fn, has_aux=True)(params, batch)
        updates, opt_state = optimiser.update(grads, opt_state, params)
        return optax.apply_updates(params, updates), opt_state, diagnostics

    rng = np.random.default_rng(0)
    n = args.minibatch

    def uniform(shape, scale):
        return jnp.asarray(scale * (rng.random(shape, dtype=np.float32) - 0.5))

    batch = (
        uniform((n, args.obs_dim), 2.0),
        uniform((n, args.action_dim), 2.0),
        uniform((n,), 1.0),
        uniform((n,), 1.0),
        uniform((n,), 1.0),
        uniform((n,), 1.0),
    )
    params, opt_state, diagnostics = update(params, opt_state, batch)  # compile and warm up
    jax.block_until_ready((params, diagnostics))
    cpu_start = time.process_time()  # CPU time of all the process's threads
    start = time.perf_counter()
    for _ in range(args.minibatches):
        params, opt_state, diagnostics = update(params, opt_state, batch)
        # rlpkg reads its diagnostics back every minibatch: so does this.
        jax.device_get(diagnostics)
    jax.block_until_ready(params)
    seconds = time.perf_counter() - start
    cpu_seconds = time.process_time() - cpu_start
    print(
        json.dumps(
            {
                "backend": "jax-" + jax.default_backend(),
                "jax_version": jax.__version__,
                "parameters": int(n_params),
                "minibatch": n,
                "minibatches": args.minibatches,
                "samples_per_second": n * args.minibatches / seconds,
                "ms_per_minibatch": 1e3 * seconds / args.minibatches,
                "samples_per_cpu_second": n * args.minibatches / cpu_seconds,
            }
        )
    )


if __name__ == "__main__":
    main()
