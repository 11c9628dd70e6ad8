"""
Monte-Carlo returns, next actions and λ-returns checked end to end against a reference that never reads the buffer's
bookkeeping.

The other λ tests compute their expected values from the buffer's own next actions and episode marks. Here random
episodes (several envs whose episodes end at different steps, terminations, time-limit truncations, cuts by an env
reset, a ring that wraps) are written both into the buffer and into a plain per-env log of what happened; returns and
next actions are recomputed from the log alone, the λ-returns by the recursion of ``sb3_offon.common.lambda_returns``:

    G_t = R_t + gamma^k [(1 - λ c) V(s_{t+k}) + λ c G_{t+n}]

over the n-step window R_t of k <= n rewards, with c = 1 after the greedy action and 1 - δ2 otherwise (Peng's Q(λ) at
δ2 = 0, Watkins's at 1); a window that ends its episode bootstraps from V (a truncation or cut) or not (a termination).
"""

import numpy as np
import pytest
from gymnasium import spaces

from sb3_offon import OffOnNStepReplayBuffer, OffOnReplayBuffer
from sb3_offon.common.lambda_returns import compute_lambda_returns

N_ACTIONS = 5
OBS_SPACE = spaces.Box(-np.inf, np.inf, shape=(1,), dtype=np.float32)
GAMMA, LAM = 0.9, 0.7


def target_values(next_observations: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A stand-in target network: V(s) = s / 10, greedy action s mod 5 (observations are integer ids)."""
    ids = np.asarray(next_observations).reshape(-1)
    return ids.astype(np.float32) * 0.1, ids.astype(np.int64) % N_ACTIONS


def make_buffer(n_envs: int, size: int, n_steps: int, optimize_memory_usage: bool) -> OffOnReplayBuffer:
    action_space = spaces.Discrete(N_ACTIONS)
    if n_steps > 1:
        return OffOnNStepReplayBuffer(
            size * n_envs, OBS_SPACE, action_space, "cpu", n_envs=n_envs, n_steps=n_steps, gamma=GAMMA
        )
    return OffOnReplayBuffer(
        size * n_envs,
        OBS_SPACE,
        action_space,
        "cpu",
        n_envs=n_envs,
        optimize_memory_usage=optimize_memory_usage,
        handle_timeout_termination=not optimize_memory_usage,
        gamma=GAMMA,
    )


def play(buffer: OffOnReplayBuffer, n_adds: int, cuts: bool, seed: int) -> list[list[dict]]:
    """Random episodes into ``buffer``; per env, the log of each step: reward, action, next state, how it ended."""
    rng = np.random.default_rng(seed)
    n_envs = buffer.n_envs
    log: list[list[dict]] = [[] for _ in range(n_envs)]
    observations = rng.integers(0, 50, n_envs).astype(np.float32)
    for _ in range(n_adds):
        if cuts and log[0] and rng.uniform() < 0.05:
            # A new learn() resets the envs: every running episode is cut where it stands
            buffer.end_open_episodes()
            for steps in log:
                steps[-1]["end"] = steps[-1]["end"] or "cut"
            observations = rng.integers(0, 50, n_envs).astype(np.float32)
        dones = rng.uniform(size=n_envs) < 0.15
        truncated = dones & (rng.uniform(size=n_envs) < 0.5)
        actions = rng.integers(0, N_ACTIONS, n_envs)
        next_observations = rng.integers(0, 50, n_envs).astype(np.float32)
        rewards = rng.normal(size=n_envs).astype(np.float32)
        infos = [{"TimeLimit.truncated": bool(truncated[env])} if dones[env] else {} for env in range(n_envs)]
        buffer.add(observations[:, None], next_observations[:, None], actions[:, None], rewards, dones, infos)
        for env, steps in enumerate(log):
            end = ("truncated" if truncated[env] else "terminated") if dones[env] else None
            step = {"reward": float(rewards[env]), "action": int(actions[env]), "next": next_observations[env]}
            steps.append({**step, "end": end})
        # A VecEnv resets a finished episode's env: the next step starts from a new observation
        observations = np.where(dones, rng.integers(0, 50, n_envs), next_observations).astype(np.float32)
    return log


def reference_returns(
    steps: list[dict], first: int, n_steps: int, qlearning_prob: float, cut_is_terminal: bool, truncation_is_terminal: bool
) -> dict[int, float]:
    """The λ-returns of one env's steps ``first``.. (the ones the buffer still holds), from its log alone."""
    newest = len(steps) - 1
    returns: dict[int, float] = {}
    for t in reversed(range(first, len(steps))):
        window_return, k = 0.0, 0
        while True:  # the n-step window: n rewards, fewer where the episode ends or the log does
            window_return += GAMMA**k * steps[t + k]["reward"]
            k += 1
            if k == n_steps or steps[t + k - 1]["end"] is not None or t + k - 1 == newest:
                break
        last = steps[t + k - 1]
        value, greedy = (float(x[0]) for x in target_values(np.array([last["next"]])))
        if last["end"] == "terminated" or (last["end"] == "truncated" and truncation_is_terminal):
            returns[t] = window_return
        elif last["end"] is not None or t + k - 1 == newest:
            # Cut or truncated: bootstrapped, or nothing after it with cut_is_terminal; a running episode's newest
            # step always bootstraps (its episode goes on)
            still_running = last["end"] is None
            returns[t] = window_return + GAMMA**k * (0.0 if cut_is_terminal and not still_running else value)
        else:
            trace = 1.0 if steps[t + k]["action"] == int(greedy) else 1.0 - qlearning_prob
            returns[t] = window_return + GAMMA**k * ((1 - LAM * trace) * value + LAM * trace * returns[t + n_steps])
    return returns


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize(
    "n_envs, size, n_adds, n_steps, optimize_memory_usage",
    [
        (3, 16, 9, 1, False),  # the ring not yet full
        (3, 16, 53, 1, False),  # wrapped three times
        (2, 16, 53, 1, True),  # optimize_memory_usage: one slot fewer, truncations stored as terminations
        (3, 16, 53, 3, False),  # n-step windows
        (2, 8, 70, 2, False),
        (1, 5, 23, 4, False),  # windows nearly as long as the ring
    ],
)
@pytest.mark.parametrize("qlearning_prob", [0.0, 0.4, 1.0])
@pytest.mark.parametrize("cut_is_terminal", [False, True])
def test_lambda_returns_match_a_reference_from_the_trajectory_log(
    seed, n_envs, size, n_adds, n_steps, optimize_memory_usage, qlearning_prob, cut_is_terminal
):
    buffer = make_buffer(n_envs, size, n_steps, optimize_memory_usage)
    # With optimize_memory_usage a cut transition's next observation is overwritten by the next episode's first
    # (documented, as in SB3): no cuts there
    log = play(buffer, n_adds, cuts=not optimize_memory_usage, seed=seed)
    held = size - (1 if optimize_memory_usage and buffer.full else 0)
    first = n_adds - min(n_adds, held)
    cache = compute_lambda_returns(buffer, target_values, 10**9, 10**6, GAMMA, LAM, qlearning_prob, cut_is_terminal, key=0)
    expected = {}
    for env, steps in enumerate(log):
        by_step = reference_returns(steps, first, n_steps, qlearning_prob, cut_is_terminal, optimize_memory_usage)
        expected.update({(t % size, env): value for t, value in by_step.items()})
    got = {(int(slot), int(env)): float(g) for slot, env, g in zip(cache.slots, cache.envs, cache.returns, strict=True)}
    assert got.keys() == expected.keys()
    for key, value in expected.items():
        assert got[key] == pytest.approx(value, rel=1e-5, abs=1e-5), key


def reference_episodes(steps: list[dict], drop_truncated: bool) -> tuple[list[float], list[int]]:
    """
    One env's Monte-Carlo returns (NaN: unknown) and next actions (-1: none) of every step, from its log alone: each
    episode's returns backwards from its tail, V(s) = 0.3 s after a truncation or a cut (unknown with
    ``drop_truncated``), 0 after a termination; a running episode's returns are not known yet.
    """
    returns, next_actions = [np.nan] * len(steps), [-1] * len(steps)
    start = 0
    for t, step in enumerate(steps):
        if step["end"] is None:
            if t + 1 < len(steps):
                next_actions[t] = steps[t + 1]["action"]
            continue
        tail = 0.0 if step["end"] == "terminated" else 0.3 * float(step["next"])
        if not (drop_truncated and step["end"] != "terminated"):
            episode_return = tail
            for u in reversed(range(start, t + 1)):
                episode_return = steps[u]["reward"] + GAMMA * episode_return
                returns[u] = episode_return
        start = t + 1
    return returns, next_actions


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize(
    "n_envs, size, n_adds, n_steps, optimize_memory_usage",
    [(3, 10, 47, 1, False), (2, 10, 47, 1, True), (2, 7, 60, 3, False), (3, 16, 9, 1, False)],
)
@pytest.mark.parametrize("drop_truncated", [False, True])
def test_returns_and_next_actions_match_the_trajectory_log(
    seed, n_envs, size, n_adds, n_steps, optimize_memory_usage, drop_truncated
):
    buffer = make_buffer(n_envs, size, n_steps, optimize_memory_usage)
    buffer.truncation_value_fn = lambda observations: np.asarray(observations).reshape(-1) * 0.3
    buffer.drop_truncated_returns = drop_truncated
    log = play(buffer, n_adds, cuts=not optimize_memory_usage, seed=seed)
    for env, steps in enumerate(log):
        returns, next_actions = reference_episodes(steps, drop_truncated)
        for t in range(max(0, n_adds - size), n_adds):
            np.testing.assert_allclose(buffer.mc_returns[t % size, env], returns[t], rtol=1e-5, err_msg=f"{t}, {env}")
            assert buffer.next_actions[t % size, env] == next_actions[t], (t, env)
