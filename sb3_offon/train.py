"""
``python -m sb3_offon.train``: rl-baselines3-zoo's ``train`` with the sb3_offon algorithms registered.

Every flag of ``python -m rl_zoo3.train`` works (``--algo``, ``--env``, ``-n``, ``--seed``, ``-f``, ``--eval-freq``,
``--eval-episodes``, ``--save-freq``, ``--tensorboard-log``, ``--progress``, ``--hyperparams``, ``-optimize`` with
``--storage``/``--study-name``, ...). Without ``-conf`` the hyperparameters come from ``sb3_offon/hyperparams``;
``-conf paper`` selects the paper's settings (see :mod:`sb3_offon.zoo`). String values need no quotes:
``--hyperparams mc_mixing:convex sarsa_target:expected`` (see :mod:`sb3_offon.cli_args`).

Example::

    python -m sb3_offon.train --algo offon_dqn --env CartPole-v1 --seed 0 -f logs --progress \\
        --eval-freq 10000 --eval-episodes 10 --save-freq 10000
"""

from sb3_offon.extras import zoo_required


def main() -> None:
    """Register the algorithms, then run the zoo's command line on ``sys.argv``."""
    # Imported here, not at the top: without the zoo extra, a one-line hint instead of a traceback
    with zoo_required():
        import rl_zoo3.train as zoo_train

        from sb3_offon.cli_args import use_tolerant_store_dict
        from sb3_offon.zoo import register
    register()
    # ``--hyperparams mc_mixing:convex``: unquoted strings (the zoo alone needs "mc_mixing:'convex'")
    use_tolerant_store_dict()
    zoo_train.train()


if __name__ == "__main__":
    main()
