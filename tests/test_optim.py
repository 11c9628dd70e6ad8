"""sb3_offon.optim.RMSprop: torch's RMSprop bit for bit, on the inputs that take torch's CPU slow path too."""

import copy

import pytest
import torch as th
from stable_baselines3 import DQN
from stable_baselines3.common.envs import IdentityEnv
from torch import nn

from sb3_offon import OffOnDQN
from sb3_offon.optim import TINY, RMSprop

SETTINGS = [
    dict(lr=2.5e-4, alpha=0.95, eps=0.01, centered=True),  # the MinAtar paper's
    dict(lr=1e-2),  # torch's defaults (eps 1e-8)
    dict(lr=1e-3, alpha=0.9, eps=1e-6, momentum=0.9, weight_decay=1e-2),
    dict(lr=1e-3, centered=True, momentum=0.5, maximize=True),
]


def sparse_gradients(shape: tuple[int, ...], generator: th.Generator) -> th.Tensor:
    """Gradients as a ReLU network on sparse inputs has them: a third exactly zero, some tiny, the rest normal."""
    gradient = th.randn(shape, generator=generator)
    gradient[..., ::3] = 0.0
    gradient[..., 1::7] *= 1e-21  # their squares are subnormal float32
    return gradient


def parameters(generator: th.Generator) -> list[nn.Parameter]:
    return [nn.Parameter(th.randn(64, 32, generator=generator)), nn.Parameter(th.randn(32, generator=generator))]


@pytest.mark.parametrize("settings", SETTINGS)
def test_updates_equal_torchs_bit_for_bit(settings: dict) -> None:
    generator = th.Generator().manual_seed(0)
    ours_parameters = parameters(generator)
    torch_parameters = [nn.Parameter(p.detach().clone()) for p in ours_parameters]
    ours, reference = RMSprop(ours_parameters, **settings), th.optim.RMSprop(torch_parameters, **settings)
    for step in range(100):
        for mine, theirs in zip(ours_parameters, torch_parameters, strict=True):
            gradient = sparse_gradients(tuple(mine.shape), generator)
            mine.grad, theirs.grad = gradient.clone(), gradient.clone()
        ours.step()
        reference.step()
        for mine, theirs in zip(ours_parameters, torch_parameters, strict=True):
            assert th.equal(mine, theirs), f"step {step}"
    if not settings.get("weight_decay"):  # (weight decay adds the weights to every gradient: no zeros)
        square_average = ours.state[ours_parameters[0]]["square_avg"]
        # the inputs the clamp is for did occur: exact zeros and subnormal averages
        assert (square_average == 0).any() and ((square_average > 0) & (square_average < TINY)).any()
    assert not th.isnan(ours_parameters[0]).any()


def test_state_dict_is_torchs_both_ways() -> None:
    generator = th.Generator().manual_seed(1)
    ours_parameters = parameters(generator)
    ours = RMSprop(ours_parameters, lr=1e-3, centered=True, momentum=0.9)
    for _ in range(3):
        for parameter in ours_parameters:
            parameter.grad = sparse_gradients(tuple(parameter.shape), generator)
        ours.step()
    torch_parameters = [nn.Parameter(p.detach().clone()) for p in ours_parameters]
    reference = th.optim.RMSprop(torch_parameters, lr=1e-3, centered=True, momentum=0.9)
    reference.load_state_dict(ours.state_dict())
    again = RMSprop([nn.Parameter(p.detach().clone()) for p in ours_parameters], lr=1e-3, centered=True, momentum=0.9)
    again.load_state_dict(reference.state_dict())
    for index in range(len(ours_parameters)):
        for name in ("step", "square_avg", "grad_avg", "momentum_buffer"):
            assert th.equal(reference.state[torch_parameters[index]][name], ours.state[ours_parameters[index]][name])
            reloaded = again.state[again.param_groups[0]["params"][index]][name]
            assert th.equal(reloaded, ours.state[ours_parameters[index]][name])


def test_a_negative_centred_variance_gives_eps_where_torch_gives_nan() -> None:
    # The same gradient every step: the centred variance is zero, and rounding takes it below zero for some entries
    gradient = th.full((4096,), 0.3) + th.linspace(0, 1, 4096)
    ours_parameter, torch_parameter = nn.Parameter(th.zeros(4096)), nn.Parameter(th.zeros(4096))
    ours = RMSprop([ours_parameter], lr=1e-3, alpha=0.95, eps=0.01, centered=True)
    reference = th.optim.RMSprop([torch_parameter], lr=1e-3, alpha=0.95, eps=0.01, centered=True)
    for _ in range(300):
        ours_parameter.grad, torch_parameter.grad = gradient.clone(), gradient.clone()
        ours.step()
        reference.step()
    assert th.isnan(torch_parameter).any()  # torch's square root of a negative rounding error
    assert not th.isnan(ours_parameter).any()
    finite = ~th.isnan(torch_parameter)
    assert th.equal(ours_parameter[finite], torch_parameter[finite])


@pytest.mark.parametrize("settings", [dict(foreach=True), dict(eps=1e-12), dict(lr=th.tensor(0.01))])
def test_what_the_fast_path_does_not_cover_runs_torchs_step(settings: dict, monkeypatch: pytest.MonkeyPatch) -> None:
    calls = []
    original = th.optim.RMSprop.step

    def counting_step(self, closure=None):
        calls.append(1)
        return original(self, closure)

    monkeypatch.setattr(th.optim.RMSprop, "step", counting_step)
    parameter = nn.Parameter(th.ones(3))
    optimizer = RMSprop([parameter], **settings)
    parameter.grad = th.ones(3)
    optimizer.step()
    assert calls == [1]
    assert not th.equal(parameter.detach(), th.ones(3))
    calls.clear()
    RMSprop([parameter]).step()  # the default settings take the fast path
    assert calls == []


def test_closure_loss_is_returned() -> None:
    parameter = nn.Parameter(th.ones(2))
    optimizer = RMSprop([parameter], lr=0.1)

    def closure() -> th.Tensor:
        optimizer.zero_grad()
        loss = (parameter**2).sum()
        loss.backward()
        return loss

    assert optimizer.step(closure).item() == pytest.approx(2.0)
    assert (parameter < 1).all()


@pytest.mark.parametrize("algo_class", [DQN, OffOnDQN])
def test_training_with_it_equals_training_with_torchs(algo_class: type[DQN]) -> None:
    """Same seed, same settings, either optimizer: the same network after training (ReLU units that die give zeros)."""
    networks = []
    for optimizer_class in (th.optim.RMSprop, RMSprop):
        model = algo_class(
            "MlpPolicy",
            IdentityEnv(8),
            learning_starts=50,
            batch_size=16,
            train_freq=1,
            target_update_interval=50,
            policy_kwargs=dict(
                net_arch=[32], optimizer_class=optimizer_class, optimizer_kwargs=dict(alpha=0.95, eps=0.01, centered=True)
            ),
            seed=0,
            device="cpu",
        )
        model.learn(400)
        assert type(model.policy.optimizer) is optimizer_class
        networks.append(copy.deepcopy(model.policy.q_net.state_dict()))
    assert networks[0].keys() == networks[1].keys()
    for name in networks[0]:
        assert th.equal(networks[0][name], networks[1][name]), name
