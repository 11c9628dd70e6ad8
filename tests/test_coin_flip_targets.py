"""OffOnDQN's coin-flip targets (``coin_flip_targets.py``): each kind of target and the choice among them, against
targets computed the plain way on a crafted minibatch with every case (known and unknown returns and next actions)."""

import numpy as np
import pytest
import torch as th

from sb3_offon import PAPER_TARGETS, OffOnDQN
from sb3_offon.common.buffers import OffOnReplayBufferSamples

SMALL = dict(learning_starts=100, buffer_size=2000, batch_size=32, policy_kwargs=dict(net_arch=[16]), device="cpu")


def crafted_batch(model: OffOnDQN, batch_size: int = 400) -> OffOnReplayBufferSamples:
    """A minibatch with every case: known/unknown returns, known/unknown next actions, terminal or not."""
    gen = th.Generator().manual_seed(0)
    obs_dim = model.observation_space.shape[0]
    n_actions = int(model.action_space.n)
    mc_returns = th.rand(batch_size, 1, generator=gen) * 50
    mc_returns[::3] = float("nan")
    next_actions = th.randint(0, n_actions, (batch_size, 1), generator=gen)
    next_actions[1::4] = -1
    dones = (th.rand(batch_size, 1, generator=gen) < 0.2).float()
    return OffOnReplayBufferSamples(
        observations=th.randn(batch_size, obs_dim, generator=gen),
        actions=th.randint(0, n_actions, (batch_size, 1), generator=gen),
        next_observations=th.randn(batch_size, obs_dim, generator=gen),
        dones=dones,
        rewards=th.randn(batch_size, 1, generator=gen),
        discounts=None,
        next_actions=next_actions,
        mc_returns=mc_returns,
    )


def reference_targets(model: OffOnDQN, data: OffOnReplayBufferSamples):
    """Each kind of target, computed the plain way."""
    with th.no_grad():
        next_q = model.q_net_target(data.next_observations)
        not_done = 1 - data.dones
        qlearning = data.rewards + not_done * model.gamma * next_q.max(dim=1, keepdim=True).values
        sarsa_next = next_q.gather(1, data.next_actions.clamp(min=0))
        sarsa = th.where(data.next_actions >= 0, data.rewards + not_done * model.gamma * sarsa_next, qlearning)
        greedy = model.q_net(data.next_observations).argmax(dim=1, keepdim=True)
        eps = model.exploration_rate
        expected_next = eps * next_q.mean(dim=1, keepdim=True) + (1 - eps) * next_q.gather(1, greedy)
        expected = data.rewards + not_done * model.gamma * expected_next
    return qlearning, sarsa, expected


def targets_at(model: OffOnDQN, data, mc: float, qlearning: float, seed: int = 0):
    """The targets and their masks (NumPy) at these probabilities, drawn as train() draws them."""
    model.mc_prob, model.qlearning_prob = mc, qlearning
    uniforms = np.random.default_rng(seed).random((2, len(data.rewards), 1), dtype=np.float32)
    targets, use_mc, use_sarsa, _ = choose_and_compute(model, data, uniforms[0] < mc, uniforms[1] >= qlearning)
    return targets, mask_tensor(use_mc), mask_tensor(use_sarsa)


def choose_and_compute(model: OffOnDQN, data, mc_drawn: np.ndarray, sarsa_drawn: np.ndarray):
    """The target choice from the draws (on the host, as train() makes it), then the targets."""
    use_mc, use_sarsa = model._target_choice(data.mc_returns.numpy(), data.next_actions.numpy(), mc_drawn, sarsa_drawn)
    with th.no_grad():
        targets, bound_active = model._targets(data, use_mc, use_sarsa)
    return targets, use_mc, use_sarsa, bound_active


def mask_tensor(mask: np.ndarray | None) -> th.Tensor | None:
    return None if mask is None else th.as_tensor(mask)


@pytest.fixture
def model():
    # A fresh model per test, with the paper's coin flips: tests set probabilities, the exploration rate and options on it
    return OffOnDQN("MlpPolicy", "CartPole-v1", seed=0, **PAPER_TARGETS, **SMALL)


def test_qlearning_target_at_mc_0_qlearning_1(model):
    data = crafted_batch(model)
    qlearning, _, _ = reference_targets(model, data)
    targets, use_mc, use_sarsa = targets_at(model, data, mc=0.0, qlearning=1.0)
    th.testing.assert_close(targets, qlearning)
    assert use_mc is None and use_sarsa is None


def test_mc_target_at_mc_1_where_the_return_is_known(model):
    data = crafted_batch(model)
    qlearning, _, _ = reference_targets(model, data)
    targets, use_mc, _ = targets_at(model, data, mc=1.0, qlearning=1.0)
    known = ~th.isnan(data.mc_returns)
    th.testing.assert_close(targets[known], data.mc_returns[known])
    th.testing.assert_close(targets[~known], qlearning[~known])
    assert th.equal(use_mc, known)


def test_sampled_sarsa_target_at_qlearning_0(model):
    data = crafted_batch(model)
    _, sarsa, _ = reference_targets(model, data)
    targets, _, use_sarsa = targets_at(model, data, mc=0.0, qlearning=0.0)
    th.testing.assert_close(targets, sarsa)
    assert th.equal(use_sarsa, data.next_actions >= 0), "unknown next actions fall back to Q-learning"


def test_expected_sarsa_target_at_qlearning_0(model):
    data = crafted_batch(model)
    model.exploration_rate = 0.3
    _, _, expected = reference_targets(model, data)
    model.sarsa_target = "expected"
    targets, _, use_sarsa = targets_at(model, data, mc=0.0, qlearning=0.0)
    th.testing.assert_close(targets, expected)
    assert bool(use_sarsa.all())


def test_convex_mixing(model):
    data = crafted_batch(model)
    qlearning, _, _ = reference_targets(model, data)
    model.mc_mixing = "convex"
    targets, _, _ = targets_at(model, data, mc=0.25, qlearning=1.0)
    known = ~th.isnan(data.mc_returns)
    th.testing.assert_close(targets[known], 0.25 * data.mc_returns[known] + 0.75 * qlearning[known])
    th.testing.assert_close(targets[~known], qlearning[~known])


def test_max_mixing_uses_the_return_as_a_lower_bound(model):
    data = crafted_batch(model)
    qlearning, sarsa, _ = reference_targets(model, data)
    # Returns around the TD targets, so that the bound is above them for some samples and below for others
    data = data._replace(mc_returns=qlearning + th.linspace(-1.0, 1.0, len(qlearning)).reshape(-1, 1))
    data.mc_returns[::3] = float("nan")
    model.mc_mixing = "max"
    model.mc_prob, model.qlearning_prob = 1.0, 1.0
    all_drawn = np.ones((len(qlearning), 1), dtype=bool)
    targets, use_mc, use_sarsa, bound_active = choose_and_compute(model, data, all_drawn, ~all_drawn)
    # Half drawn for MC: the others keep their TD target (here Sarsa where a' is known), whatever G says
    half = np.arange(len(qlearning)).reshape(-1, 1) % 2 == 0
    model.qlearning_prob = 0.0
    mixed, _, use_sarsa_mixed, _ = choose_and_compute(model, data, half, all_drawn)
    known = ~th.isnan(data.mc_returns)
    above = known & (data.mc_returns > qlearning)
    th.testing.assert_close(targets[above], data.mc_returns[above])
    th.testing.assert_close(targets[~above], qlearning[~above])
    assert th.equal(bound_active.cpu(), above)
    assert use_sarsa is None and th.equal(th.as_tensor(use_mc), known)
    # With Sarsa in play, a sample drawn for MC keeps its Sarsa draw: y = max(G, y_Sarsa)
    drawn = th.as_tensor(half) & known
    td = th.where(th.as_tensor(use_sarsa_mixed), sarsa, qlearning)
    th.testing.assert_close(mixed[drawn], th.maximum(data.mc_returns, td)[drawn])
    th.testing.assert_close(mixed[~drawn], td[~drawn])
    assert bool(th.as_tensor(use_sarsa_mixed)[drawn].any()), "MC-drawn samples keep their Sarsa targets"


def test_random_choice_follows_the_probabilities(model):
    data = crafted_batch(model, batch_size=20_000)
    qlearning, sarsa, _ = reference_targets(model, data)
    targets, use_mc, use_sarsa = targets_at(model, data, mc=0.3, qlearning=0.6)
    known_return = ~th.isnan(data.mc_returns)
    known_action = data.next_actions >= 0
    # Every target is exactly one of the three kinds, as the masks say
    th.testing.assert_close(targets[use_mc], data.mc_returns[use_mc])
    th.testing.assert_close(targets[use_sarsa], sarsa[use_sarsa])
    rest = ~use_mc & ~use_sarsa
    th.testing.assert_close(targets[rest], qlearning[rest])
    # Frequencies: P(MC | G known) = 0.3; P(Sarsa | not MC, a' known) = 0.4 (standard error here < 0.006)
    assert abs(use_mc[known_return].float().mean().item() - 0.3) < 0.03
    assert not bool(use_mc[~known_return].any())
    candidates = ~use_mc & known_action
    assert abs(use_sarsa[candidates].float().mean().item() - 0.4) < 0.03


def test_n_step_discounts_are_respected(model):
    data = crafted_batch(model)._replace(discounts=th.full((400, 1), 0.5))
    targets, _, _ = targets_at(model, data, mc=0.0, qlearning=0.0)
    with th.no_grad():
        next_q = model.q_net_target(data.next_observations)
    bootstrap = th.where(
        data.next_actions >= 0, next_q.gather(1, data.next_actions.clamp(min=0)), next_q.max(1, keepdim=True).values
    )
    th.testing.assert_close(targets, data.rewards + (1 - data.dones) * 0.5 * bootstrap)


@pytest.mark.parametrize("n_steps", [1, 3])
@pytest.mark.parametrize("double_q", [False, True])
def test_train_regresses_on_targets_rebuilt_from_the_stored_transitions(monkeypatch, n_steps: int, double_q: bool) -> None:
    """
    End to end through ``train()``: the targets it regresses on, rebuilt from the buffer's raw arrays (rewards, flags,
    the action stored in the next slot, next observations), its draws and the two networks, with short episodes (a
    15-step time limit) so that minibatches hold terminations, truncations and n-step windows cut by them.
    """
    import gymnasium as gym
    from stable_baselines3.common.env_util import make_vec_env

    from sb3_offon.offon_dqn import offon_dqn as offon_dqn_module

    gamma, mc_prob, qlearning_prob, gradient_steps, batch_size = 0.9, 0.3, 0.4, 4, 16
    env = make_vec_env(lambda: gym.make("CartPole-v1", max_episode_steps=15), n_envs=1, seed=3)
    model = OffOnDQN(
        "MlpPolicy", env, seed=0, double_q=double_q, n_steps=n_steps, gamma=gamma, learning_starts=10**6,
        target_update_interval=10**6, exploration_final_eps=1.0, policy_kwargs=dict(net_arch=[8]), device="cpu",
        **PAPER_TARGETS,
    )  # fmt: skip
    with th.no_grad():  # the online network apart from the target network, so that double Q shows
        for parameter in model.q_net.parameters():
            parameter.add_(th.randn_like(parameter))
    model.learn(300)  # transitions only: learning starts later
    captured = []

    def capture(prediction: th.Tensor, target: th.Tensor) -> th.Tensor:
        captured.append(target.detach().clone())
        return th.nn.functional.smooth_l1_loss(prediction, target)

    monkeypatch.setitem(offon_dqn_module.LOSS_FUNCTIONS, "huber", capture)
    model.mc_schedule = lambda _: mc_prob
    model.qlearning_schedule = lambda _: qlearning_prob
    model.learning_rate, model.lr_schedule = 0.0, lambda _: 0.0  # the networks stay as they are
    sampling_state, draws = np.random.get_state(), np.random.default_rng()
    draws.bit_generator.state = model.target_rng.bit_generator.state
    model.train(gradient_steps, batch_size)

    np.random.set_state(sampling_state)  # the same minibatch indices as SB3's sample()
    uniforms = draws.random((2, gradient_steps * batch_size, 1), dtype=np.float32)
    buffer, stored = model.replay_buffer, model.replay_buffer.pos
    rewards, actions = buffer.rewards[:stored, 0], buffer.actions[:stored, 0]
    dones, timeouts = buffer.dones[:stored, 0].astype(bool), buffer.timeouts[:stored, 0].astype(bool)
    next_observations = th.as_tensor(buffer.next_observations[:stored, 0])
    with th.no_grad():
        target_q, online_q = model.q_net_target(next_observations).numpy(), model.q_net(next_observations).numpy()
    sample = 0
    for step in range(gradient_steps):
        for row, t in enumerate(np.random.randint(0, stored, size=batch_size)):
            window_return, discount, last = 0.0, 1.0, t
            for offset in range(n_steps):  # the n-step window, stopped by an episode's end or the newest transition
                last = t + offset
                window_return += discount * rewards[last]
                discount *= gamma
                if dones[last] or last == stored - 1:
                    break
            went_on = last - t + 1 == n_steps and not dones[last] and last < stored - 1
            greedy = online_q[last].argmax() if double_q else target_q[last].argmax()
            use_mc = not np.isnan(buffer.mc_returns[t, 0]) and uniforms[0, sample, 0] < mc_prob
            use_sarsa = went_on and uniforms[1, sample, 0] >= qlearning_prob
            terminated = dones[last] and not timeouts[last]
            bootstrap = target_q[last][int(actions[last + 1, 0])] if use_sarsa else target_q[last][greedy]
            expected = buffer.mc_returns[t, 0] if use_mc else window_return + (0.0 if terminated else discount * bootstrap)
            assert captured[step][row, 0].item() == pytest.approx(expected, rel=1e-5, abs=1e-5), (step, row, t)
            sample += 1
    assert timeouts.any() and (dones & ~timeouts).any(), "the stored episodes end both ways"
