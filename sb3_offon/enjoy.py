"""
``python -m sb3_offon.enjoy``: rl-baselines3-zoo's ``enjoy`` (replay a trained agent) with the sb3_offon algorithms.

Every flag of ``python -m rl_zoo3.enjoy`` works (``--algo``, ``--env``, ``-f``, ``-n``, ``--exp-id``,
``--no-render``, ``--load-best``, ``--load-checkpoint``, ``--deterministic``, ...).

Example::

    python -m sb3_offon.enjoy --algo offon_dqn --env CartPole-v1 -f logs -n 2000 --no-render
"""

import re
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

from stable_baselines3.common.base_class import BaseAlgorithm

from sb3_offon.extras import zoo_required
from sb3_offon.train import prog

# The zoo's words when ``-f``/``--exp-id``/``--load-*`` name no saved model (rl_zoo3.utils.get_model_path): an assertion
# for a missing folder, a ValueError for a missing file
NO_MODEL = re.compile(r"The .* folder was not found|No (model|checkpoint) found for ")


class ReplayLoader:
    """
    Stands for an off-policy algorithm in ``rl_zoo3.enjoy``: loads it with a one-transition replay buffer.

    The zoo's ``enjoy`` shrinks the replay buffer only for the algorithms of a hard-coded list of names (``dqn``,
    ``qrdqn``, ...); any other off-policy model would allocate its full buffer (gigabytes on Atari) just to be
    replayed. ``enjoy`` only calls ``ALGOS[algo].load``, so this stand-in supplies the same keyword arguments the zoo
    gives to ``dqn``.

    :param algo_class: the algorithm class to load
    """

    def __init__(self, algo_class: type[BaseAlgorithm]) -> None:
        self.algo_class = algo_class

    def load(self, path: Any, **kwargs: Any) -> BaseAlgorithm:
        """
        Load a saved model for replay.

        :param path: the saved model (zip)
        :param kwargs: the keyword arguments of ``BaseAlgorithm.load``
        :return: the loaded model
        """
        kwargs.setdefault("buffer_size", 1)
        # A memory-efficient buffer cannot be combined with SB3's default timeout handling: disable it, as the zoo does
        kwargs.setdefault("optimize_memory_usage", False)
        return self.algo_class.load(path, **kwargs)


@contextmanager
def no_model_in_one_line() -> Iterator[None]:
    """
    Turn "no saved model there" (a wrong ``-f``, ``--algo``, ``--env`` or ``--exp-id``; the zoo asserts or raises a
    ``ValueError`` with a traceback) into one line on stderr with exit status 2. Any other error keeps its traceback.

    :raises SystemExit: after printing the line
    """
    try:
        yield
    except (AssertionError, ValueError) as error:
        if not NO_MODEL.match(str(error)):
            raise
        print(f"{prog('enjoy')}: error: {error}; -f takes the folder that training's -f wrote", file=sys.stderr)
        raise SystemExit(2) from None


def main() -> None:
    """Register the algorithms, then run the zoo's ``enjoy`` command line on ``sys.argv``."""
    # Imported here, not at the top: without the zoo extra, a one-line hint instead of a traceback
    with zoo_required():
        import rl_zoo3.enjoy as zoo_enjoy

        from sb3_offon.cli_args import use_tolerant_store_dict
        from sb3_offon.minatar_envs import MinAtarNotInstalledError
        from sb3_offon.train import one_thread_by_default, run_errors_in_one_line
        from sb3_offon.zoo import ALGOS, register
    register()
    # ``--env-kwargs key:word``: unquoted strings, as for training
    use_tolerant_store_dict()
    # One torch thread unless --num-threads says otherwise, as for training
    sys.argv[1:] = one_thread_by_default(sys.argv[1:])
    # A copy for enjoy alone: training keeps the real classes
    zoo_enjoy.ALGOS = {**zoo_enjoy.ALGOS, **{name: ReplayLoader(cls) for name, cls in ALGOS.items()}}  # type: ignore[assignment,misc]
    # MinAtar not installed where a MinAtar model is replayed: one line, as for training
    with no_model_in_one_line(), run_errors_in_one_line((), (MinAtarNotInstalledError,), command="enjoy"):
        zoo_enjoy.enjoy()


if __name__ == "__main__":
    main()
