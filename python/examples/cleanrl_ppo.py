"""CleanRL's continuous-action PPO (ppo_continuous_action.py, torch) on ``rlpkg.make_vec``.

    python python/examples/cleanrl_ppo.py                                   # Pendulum-v1, 1M steps
    python python/examples/cleanrl_ppo.py --env-id Transport-v0 --config python/tests/transport-small.toml \
        --total-timesteps 20000

The structure and defaults are CleanRL's (one file: arguments, ``Agent``, rollout, GAE, clipped
surrogate, value clipping, entropy bonus, linear learning-rate annealing; ClipAction,
NormalizeObservation and NormalizeReward wrappers). The environment uses Gymnasium's default
next-step autoreset: the step after an episode ends returns the new episode's first observation
and ignores its action, so that transition is masked out of the losses and the advantage
recursion stops at every done. A truncated episode bootstraps from the value of its terminal
observation, which next-step autoreset hands over as the next observation.
"""

from __future__ import annotations

import argparse
import random
import time

import gymnasium as gym
import numpy as np
import torch
import torch.nn as nn
from torch.distributions.normal import Normal

import rlpkg


def parse_args(argv=None):
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--env-id", default="Pendulum-v1", choices=["Pendulum-v1", "Transport-v0"])
    p.add_argument("--config", default=None, help="Transport-v0 configuration file")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--torch-deterministic", type=int, default=1)
    p.add_argument("--total-timesteps", type=int, default=1_000_000)
    p.add_argument("--learning-rate", type=float, default=3e-4)
    p.add_argument("--num-envs", type=int, default=1)
    p.add_argument("--num-steps", type=int, default=2048)
    p.add_argument("--anneal-lr", type=int, default=1)
    p.add_argument("--gamma", type=float, default=0.99)
    p.add_argument("--gae-lambda", type=float, default=0.95)
    p.add_argument("--num-minibatches", type=int, default=32)
    p.add_argument("--update-epochs", type=int, default=10)
    p.add_argument("--norm-adv", type=int, default=1)
    p.add_argument("--clip-coef", type=float, default=0.2)
    p.add_argument("--clip-vloss", type=int, default=1)
    p.add_argument("--ent-coef", type=float, default=0.0)
    p.add_argument("--vf-coef", type=float, default=0.5)
    p.add_argument("--max-grad-norm", type=float, default=0.5)
    p.add_argument("--target-kl", type=float, default=None)
    p.add_argument("--threads", type=int, default=1, help="torch and environment threads")
    args = p.parse_args(argv)
    args.batch_size = args.num_envs * args.num_steps
    args.minibatch_size = max(1, args.batch_size // args.num_minibatches)
    args.num_iterations = max(1, args.total_timesteps // args.batch_size)
    return args


def make_env(args):
    kwargs = {"config": args.config} if args.env_id == "Transport-v0" else {}
    envs = rlpkg.make_vec(args.env_id, args.num_envs, num_threads=args.threads, **kwargs)
    envs = gym.wrappers.vector.RecordEpisodeStatistics(envs)
    envs = gym.wrappers.vector.ClipAction(envs)
    envs = gym.wrappers.vector.NormalizeObservation(envs)
    envs = gym.wrappers.vector.NormalizeReward(envs, gamma=args.gamma)
    return envs


def layer_init(layer, std=np.sqrt(2), bias_const=0.0):
    torch.nn.init.orthogonal_(layer.weight, std)
    torch.nn.init.constant_(layer.bias, bias_const)
    return layer


class Agent(nn.Module):
    def __init__(self, envs):
        super().__init__()
        obs_dim = int(np.prod(envs.single_observation_space.shape))
        act_dim = int(np.prod(envs.single_action_space.shape))
        self.critic = nn.Sequential(
            layer_init(nn.Linear(obs_dim, 64)), nn.Tanh(),
            layer_init(nn.Linear(64, 64)), nn.Tanh(),
            layer_init(nn.Linear(64, 1), std=1.0),
        )
        self.actor_mean = nn.Sequential(
            layer_init(nn.Linear(obs_dim, 64)), nn.Tanh(),
            layer_init(nn.Linear(64, 64)), nn.Tanh(),
            layer_init(nn.Linear(64, act_dim), std=0.01),
        )
        self.actor_logstd = nn.Parameter(torch.zeros(1, act_dim))

    def get_value(self, x):
        return self.critic(x)

    def get_action_and_value(self, x, action=None):
        action_mean = self.actor_mean(x)
        action_std = torch.exp(self.actor_logstd.expand_as(action_mean))
        probs = Normal(action_mean, action_std)
        if action is None:
            action = probs.sample()
        return action, probs.log_prob(action).sum(1), probs.entropy().sum(1), self.critic(x)


def train(args):
    """Runs PPO; returns ``(agent, episodes)`` with every finished episode's ``(step, return,
    length)``."""
    random.seed(args.seed)
    np.random.seed(args.seed)
    torch.manual_seed(args.seed)
    torch.backends.cudnn.deterministic = bool(args.torch_deterministic)
    torch.set_num_threads(args.threads)
    device = torch.device("cpu")

    envs = make_env(args)
    assert isinstance(envs.single_action_space, gym.spaces.Box), "only continuous action space is supported"
    agent = Agent(envs).to(device)
    optimizer = torch.optim.Adam(agent.parameters(), lr=args.learning_rate, eps=1e-5)

    shape = (args.num_steps, args.num_envs)
    obs = torch.zeros(shape + envs.single_observation_space.shape).to(device)
    actions = torch.zeros(shape + envs.single_action_space.shape).to(device)
    logprobs = torch.zeros(shape).to(device)
    rewards = torch.zeros(shape).to(device)
    terminations = torch.zeros(shape).to(device)
    dones = torch.zeros(shape).to(device)
    # valid[t]: the transition at t is a real one (not the autoreset step after a done).
    valid = torch.zeros(shape, dtype=torch.bool).to(device)
    values = torch.zeros(shape).to(device)

    global_step = 0
    start_time = time.time()
    episodes: list[tuple[int, float, int]] = []
    next_obs, _ = envs.reset(seed=args.seed)
    next_obs = torch.Tensor(next_obs).to(device)
    autoreset = np.zeros(args.num_envs, dtype=bool)

    for iteration in range(1, args.num_iterations + 1):
        if args.anneal_lr:
            frac = 1.0 - (iteration - 1.0) / args.num_iterations
            optimizer.param_groups[0]["lr"] = frac * args.learning_rate

        for step in range(args.num_steps):
            global_step += args.num_envs
            obs[step] = next_obs
            valid[step] = torch.from_numpy(~autoreset)
            with torch.no_grad():
                action, logprob, _, value = agent.get_action_and_value(next_obs)
                values[step] = value.flatten()
            actions[step] = action
            logprobs[step] = logprob

            next_obs, reward, terminated, truncated, infos = envs.step(action.cpu().numpy())
            done = np.logical_or(terminated, truncated)
            rewards[step] = torch.tensor(reward, dtype=torch.float32).to(device).view(-1)
            terminations[step] = torch.tensor(terminated, dtype=torch.float32).to(device)
            dones[step] = torch.tensor(done, dtype=torch.float32).to(device)
            next_obs = torch.Tensor(next_obs).to(device)
            autoreset = done

            if "episode" in infos:
                for i in np.flatnonzero(infos["_episode"]):
                    r, l = float(infos["episode"]["r"][i]), int(infos["episode"]["l"][i])
                    episodes.append((global_step, r, l))

        # GAE over the valid transitions: at a done, a termination adds no future value and a
        # truncation bootstraps from the terminal observation (the next row's observation); the
        # recursion does not cross the done.
        with torch.no_grad():
            next_value = agent.get_value(next_obs).reshape(1, -1)
            advantages = torch.zeros_like(rewards).to(device)
            lastgaelam = 0
            for t in reversed(range(args.num_steps)):
                nextvalues = next_value if t == args.num_steps - 1 else values[t + 1]
                delta = rewards[t] + args.gamma * nextvalues * (1.0 - terminations[t]) - values[t]
                advantages[t] = lastgaelam = delta + args.gamma * args.gae_lambda * (1.0 - dones[t]) * lastgaelam
            returns = advantages + values

        b_valid = valid.reshape(-1)
        b_obs = obs.reshape((-1,) + envs.single_observation_space.shape)[b_valid]
        b_logprobs = logprobs.reshape(-1)[b_valid]
        b_actions = actions.reshape((-1,) + envs.single_action_space.shape)[b_valid]
        b_advantages = advantages.reshape(-1)[b_valid]
        b_returns = returns.reshape(-1)[b_valid]
        b_values = values.reshape(-1)[b_valid]
        n = b_obs.shape[0]

        b_inds = np.arange(n)
        clipfracs = []
        for epoch in range(args.update_epochs):
            np.random.shuffle(b_inds)
            for start in range(0, n, args.minibatch_size):
                mb_inds = b_inds[start : start + args.minibatch_size]
                _, newlogprob, entropy, newvalue = agent.get_action_and_value(b_obs[mb_inds], b_actions[mb_inds])
                logratio = newlogprob - b_logprobs[mb_inds]
                ratio = logratio.exp()
                with torch.no_grad():
                    approx_kl = ((ratio - 1) - logratio).mean()
                    clipfracs += [((ratio - 1.0).abs() > args.clip_coef).float().mean().item()]
                mb_advantages = b_advantages[mb_inds]
                if args.norm_adv and len(mb_inds) > 1:
                    mb_advantages = (mb_advantages - mb_advantages.mean()) / (mb_advantages.std() + 1e-8)
                pg_loss1 = -mb_advantages * ratio
                pg_loss2 = -mb_advantages * torch.clamp(ratio, 1 - args.clip_coef, 1 + args.clip_coef)
                pg_loss = torch.max(pg_loss1, pg_loss2).mean()
                newvalue = newvalue.view(-1)
                if args.clip_vloss:
                    v_loss_unclipped = (newvalue - b_returns[mb_inds]) ** 2
                    v_clipped = b_values[mb_inds] + torch.clamp(
                        newvalue - b_values[mb_inds], -args.clip_coef, args.clip_coef
                    )
                    v_loss_clipped = (v_clipped - b_returns[mb_inds]) ** 2
                    v_loss = 0.5 * torch.max(v_loss_unclipped, v_loss_clipped).mean()
                else:
                    v_loss = 0.5 * ((newvalue - b_returns[mb_inds]) ** 2).mean()
                entropy_loss = entropy.mean()
                loss = pg_loss - args.ent_coef * entropy_loss + v_loss * args.vf_coef
                optimizer.zero_grad()
                loss.backward()
                nn.utils.clip_grad_norm_(agent.parameters(), args.max_grad_norm)
                optimizer.step()
            if args.target_kl is not None and approx_kl > args.target_kl:
                break

        recent = [r for _, r, _ in episodes[-20:]]
        mean = f"{np.mean(recent):9.2f}" if recent else "      n/a"
        sps = int(global_step / (time.time() - start_time))
        print(
            f"iteration {iteration}/{args.num_iterations}: step {global_step}, mean return (last 20) {mean}, "
            f"value loss {v_loss.item():.4f}, policy loss {pg_loss.item():.4f}, "
            f"clipfrac {np.mean(clipfracs):.3f}, SPS {sps}"
        )

    envs.close()
    return agent, episodes


if __name__ == "__main__":
    train(parse_args())
