"""OffOnDQN learns: CartPole-v1 with the repo's bundled settings is solved within their 50k steps for a fixed seed."""

from pathlib import Path

import pytest
import torch as th
import yaml
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.evaluation import evaluate_policy

from sb3_offon import OffOnDQN

HYPERPARAMS = Path(__file__).resolve().parents[1] / "hyperparams" / "offon_dqn.yml"


def bundled_settings(env_id: str) -> tuple[int, dict]:
    settings = dict(yaml.safe_load(HYPERPARAMS.read_text())[env_id])
    n_timesteps = int(settings.pop("n_timesteps"))
    policy = settings.pop("policy")
    # rl-zoo's format: policy_kwargs is a Python expression
    settings["policy_kwargs"] = eval(settings.get("policy_kwargs", "dict()"))
    return n_timesteps, {"policy": policy, **settings}


@pytest.mark.slow
def test_solves_cartpole_with_bundled_settings():
    th.set_num_threads(1)
    n_timesteps, settings = bundled_settings("CartPole-v1")
    assert n_timesteps <= 50_000
    model = OffOnDQN(env=make_vec_env("CartPole-v1", n_envs=1, seed=0), seed=0, device="cpu", **settings)
    model.learn(n_timesteps)
    mean_return, _ = evaluate_policy(model, make_vec_env("CartPole-v1", n_envs=1, seed=1000), n_eval_episodes=20)
    assert mean_return >= 475
