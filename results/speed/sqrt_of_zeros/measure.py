"""
How long torch's CPU square root takes on the values centred RMSprop takes it of, with and without raising them to the
smallest normal float32 first (which leaves ``sqrt(v) + eps`` unchanged in float32 for eps 0.01).

Part 1: 131,072 equal values (the size of MinAtar's network's largest layer): ones, zeros, 1e-30, 1e-39 (subnormal).
Part 2: the centred variance ``square_avg - grad_avg**2`` of that layer in saved models (SB3 zips, centred RMSprop),
for instance checkpoints of MinAtar runs at several steps.

Usage: python results/speed/sqrt_of_zeros/measure.py [model.zip ...]
"""

import sys
import time

import torch as th
from stable_baselines3 import DQN

import sb3_offon  # noqa: F401  (registers MinAtarCNN's module for unpickling)

TINY = th.finfo(th.float32).tiny


def best_microseconds(function, calls: int = 300, repeats: int = 5) -> float:
    function()
    best = float("inf")
    for _ in range(repeats):
        start = time.perf_counter()
        for _ in range(calls):
            function()
        best = min(best, (time.perf_counter() - start) / calls * 1e6)
    return best


def main() -> None:
    th.set_num_threads(1)
    print(f"torch {th.__version__}, one thread, best of 5 x 300 calls")
    size = 131_072
    out = th.empty(size)
    for name, value in (("1.0", 1.0), ("0.0", 0.0), ("1e-30", 1e-30), ("1e-39 (subnormal)", 1e-39)):
        values = th.full((size,), value)
        print(f"sqrt of {size} x {name:18s} {best_microseconds(lambda values=values: th.sqrt(values, out=out)):7.0f} us")
    for path in sys.argv[1:]:
        model = DQN.load(path, device="cpu")
        largest = max(model.q_net.parameters(), key=lambda parameter: parameter.numel())
        state = model.policy.optimizer.state[largest]
        variance = state["square_avg"].addcmul(state["grad_avg"], state["grad_avg"], value=-1)
        plain = best_microseconds(lambda variance=variance: variance.sqrt())
        clamped = best_microseconds(lambda variance=variance: variance.clamp(min=TINY).sqrt_())
        same = th.equal(variance.sqrt().add_(0.01), variance.clamp(min=TINY).sqrt_().add_(0.01))
        print(
            f"{path}: {model.num_timesteps} steps, largest layer {largest.numel()} weights, variance zero "
            f"{(variance == 0).float().mean():.3f}, subnormal {((variance > 0) & (variance < TINY)).float().mean():.4f}; "
            f"sqrt {plain:.0f} us, clamp then sqrt {clamped:.0f} us; sqrt + 0.01 the same: {same}"
        )


if __name__ == "__main__":
    main()
