"""
Registration of the sb3_offon algorithms into rl-baselines3-zoo (``rl_zoo3``).

The zoo has no plugin hook: its algorithms are the dict ``rl_zoo3.utils.ALGOS`` (shared by ``rl_zoo3.train``,
``rl_zoo3.exp_manager`` and ``rl_zoo3.enjoy``), its Optuna samplers the dict
``rl_zoo3.hyperparams_opt.HYPERPARAMS_SAMPLER``, and its documented way to add an algorithm is to extend them before
calling ``rl_zoo3.train.train()`` (docs/guide/sbx.md). :func:`register` does that, and also makes the bundled YAML
files the default ``-conf``:

- no ``-conf``: ``sb3_offon/hyperparams/{algo}.yml`` when this package ships one (every algorithm here and
  ``dqn``, a copy of the zoo's tuned DQN entries, so that benchmarks compare like with like), else the zoo's own file;
- ``-conf paper`` (any name of a sub-folder of ``sb3_offon/hyperparams``): ``sb3_offon/hyperparams/paper/{algo}.yml``,
  the paper's own settings, found inside the installed package;
- any other ``-conf`` (a YAML or Python file, a module): the zoo's behaviour, untouched.

Its experiment manager (:class:`OffOnExperimentManager`) also writes checkpoints and resumes runs from them
(``--checkpoint-freq``, ``--resume``), refuses an env whose actions the algorithm cannot take before anything is made
(:class:`sb3_offon.zoo_checks.UnsupportedActionSpaceError`), warns when a bundled file has no settings for the env
(:class:`sb3_offon.zoo_checks.DefaultHyperparametersWarning`), and raises :class:`sb3_offon.zoo_checks.RunInterrupted`
after the model of a run cut short by Ctrl-C is saved. The checks are in :mod:`sb3_offon.zoo_checks`, the Optuna
samplers in :mod:`sb3_offon.tuning`.
"""

import contextlib
import inspect
import json
import shutil
import warnings
from pathlib import Path
from typing import Any

import rl_zoo3.enjoy as zoo_enjoy
import rl_zoo3.exp_manager as zoo_exp_manager
import rl_zoo3.hyperparams_opt as zoo_hyperparams_opt
import rl_zoo3.train as zoo_train
import rl_zoo3.utils as zoo_utils
import yaml
from rl_zoo3.exp_manager import ExperimentManager
from rl_zoo3.hyperparams_opt import convert_offpolicy_params
from rl_zoo3.utils import get_wrapper_class
from stable_baselines3 import DQN
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import EvalCallback
from stable_baselines3.common.vec_env import VecEnv

# Registers CartPoleFallPenalty-v1 and MountainCarGoalBonus-v0 (also done by ``import sb3_offon``)
import sb3_offon.envs  # noqa: F401
from sb3_offon.atari import ale_v5_kwargs
from sb3_offon.common.non_finite import NonFiniteCheck, NonFiniteChecksMixin
from sb3_offon.common.prioritized_buffers import PRIORITIZED_BUFFERS
from sb3_offon.evaluation import EpsilonGreedyEvalCallback, final_evaluation
from sb3_offon.offon_dqn import OffOnDQN
from sb3_offon.offon_qrdqn import OffOnQRDQN
from sb3_offon.qrdqn import QRDQN
from sb3_offon.resume import (
    STOPPED_FILE,
    Checkpoint,
    CheckpointError,
    RunCheckpoint,
    joined_monitor,
    n_step_reload_unflagged,
)
from sb3_offon.termination import Terminated, termination_deferred
from sb3_offon.torch_layers import DataEfficientCNN, MinAtarCNN
from sb3_offon.tuning import SAMPLERS as SAMPLERS_BY_NAME
from sb3_offon.variants import DQNMC, DQNSarsa
from sb3_offon.zoo_checks import (
    HYPERPARAMS_DIR,
    AtariSettingsNote,
    DefaultHyperparametersWarning,
    HyperparameterError,
    RunInterrupted,
    UnsupportedActionSpaceError,
    check_action_space,
    check_hyperparameter_names,
    checkpoint_folder,
    comparable,
    default_settings_note,
    raised_by_a_constructor,
)

# The names are the contract of the command line and of the log folders (logs/{algo}/...). ``dqn_nstep`` is SB3's own
# DQN under a name of its own, so that its settings (the zoo's DQN entries plus ``n_steps``) and its logs are apart
# from plain DQN's. The zoo already registers ``dqn`` and ``qrdqn`` (sb3-contrib); this package bundles their settings,
# and ``qrdqn`` trains sb3_offon.qrdqn.QRDQN, sb3-contrib's QR-DQN with its loss computed from sorted
# targets (the same results, about four times the steps per second on MinAtar).
# Every OffOnDQN name differs only in the target settings its YAML file writes out: ``offon_dqn`` is what
# ``OffOnDQN(policy, env)`` trains (its defaults), ``offon_paper`` the paper's coin flips, ``offon_mc_decay`` and
# ``offon_watkins`` two configurations of the search.
ALGOS: dict[str, type[BaseAlgorithm]] = {
    "offon_dqn": OffOnDQN,
    "offon_paper": OffOnDQN,
    "dqn_mc": DQNMC,
    "dqn_sarsa": DQNSarsa,
    "dqn_nstep": DQN,
    "offon_mc_decay": OffOnDQN,
    "offon_watkins": OffOnDQN,
    "qrdqn": QRDQN,
    "qrdqn_nstep": QRDQN,
    "offon_qrdqn": OffOnQRDQN,
}

# Former names (hyperparams/aliases.yml): each trains what its new name does and logs under the name it was given
with open(HYPERPARAMS_DIR / "aliases.yml") as aliases_file:
    ALIASES: dict[str, str] = yaml.safe_load(aliases_file)
ALGOS.update({alias: ALGOS[name] for alias, name in ALIASES.items()})
# The Optuna samplers (sb3_offon/tuning.py), under the former names too
SAMPLERS = {
    **SAMPLERS_BY_NAME,
    **{alias: SAMPLERS_BY_NAME[name] for alias, name in ALIASES.items() if name in SAMPLERS_BY_NAME},
}

# What each name trains, in a line (``--help`` lists them)
ALGO_SUMMARIES: dict[str, str] = {
    "offon_dqn": "OffOnDQN's defaults: lambda-returns, lambda 0.9, Peng's Q(lambda)",
    "offon_paper": "the paper's coin-flip targets (PAPER_TARGETS)",
    "dqn_mc": "the paper's ablation: Monte-Carlo or Q-learning targets, no Sarsa",
    "dqn_sarsa": "the paper's ablation: Q-learning or Sarsa targets, no Monte-Carlo",
    "dqn_nstep": "SB3's DQN with n-step returns (n in the YAML)",
    "offon_mc_decay": "the search's first choice: coin flips, delta1 0.99 -> 0.01, no Sarsa",
    "offon_watkins": "lambda-returns, lambda 0.9, Watkins's Q(lambda)",
    "qrdqn": "sb3-contrib's QR-DQN, its loss from sorted targets (same results, faster)",
    "qrdqn_nstep": "QR-DQN with n-step returns (sb3-contrib's n_steps, n in the YAML)",
    "offon_qrdqn": "OffOnQRDQN's defaults: QR-DQN on lambda-returns, lambda 0.9, Peng's",
    **{alias: f"former name of {name}" for alias, name in ALIASES.items()},
}


def resolve_config(algo: str, config: str | None) -> str | None:
    """
    The hyperparameter file the zoo should read for ``algo`` given the ``-conf`` argument.

    :param algo: the ``--algo`` name (a former name in ``ALIASES`` reads its new name's file)
    :param config: the ``-conf`` argument (None when absent)
    :return: the bundled ``{algo}.yml`` when ``config`` is None and this package ships one; the bundled
        ``{config}/{algo}.yml`` when ``config`` names a bundled set (``paper``); otherwise ``config`` unchanged
        (None lets the zoo use its own ``hyperparams/{algo}.yml``)
    """
    algo = ALIASES.get(algo, algo)
    if config is None:
        bundled = HYPERPARAMS_DIR / f"{algo}.yml"
        return str(bundled) if bundled.is_file() else None
    # A plain name (no path, no suffix, no dotted module) that is a bundled folder
    if config.isidentifier() and (HYPERPARAMS_DIR / config).is_dir():
        bundled = HYPERPARAMS_DIR / config / f"{algo}.yml"
        if not bundled.is_file():
            available = sorted(path.stem for path in (HYPERPARAMS_DIR / config).glob("*.yml"))
            raise FileNotFoundError(f"The bundled hyperparameter set '{config}' has no file for {algo}: {available}")
        return str(bundled)
    return config


class OffOnExperimentManager(ExperimentManager):
    """
    The zoo's ``ExperimentManager``, reading this package's hyperparameter files by default (see :func:`resolve_config`),
    and writing the checkpoints of ``--checkpoint-freq`` and going on from them with ``--resume``
    (:mod:`sb3_offon.resume`).

    The resolved path is also written back to ``args.conf_file``, so that the run's ``args.yml`` names the file
    that was actually read.

    :param args: the parsed command line (``argparse.Namespace``)
    :param algo: the ``--algo`` name
    :param positional: the other positional arguments of ``ExperimentManager``
    :param keywords: the other keyword arguments of ``ExperimentManager`` (``config`` included)
    """

    def __init__(self, args: Any, algo: str, *positional: Any, **keywords: Any) -> None:
        # Bound against the parent's signature: ``config`` is found whether it came by position or by keyword
        bound = inspect.signature(ExperimentManager.__init__).bind(self, args, algo, *positional, **keywords)
        bound.apply_defaults()
        bound.arguments["config"] = resolve_config(algo, bound.arguments["config"])
        if bound.arguments["config"] is not None and hasattr(args, "conf_file"):
            args.conf_file = bound.arguments["config"]
        super().__init__(*bound.args[1:], **bound.kwargs)
        # Checkpoints to resume from (sb3_offon.resume); the options exist when the command line of sb3_offon.train made
        # ``args``, otherwise the run has none
        self.checkpoint_freq = int(getattr(args, "checkpoint_freq", 0) or 0)
        self.resume_dir = checkpoint_folder(getattr(args, "resume", None))
        self.checkpoint_dir = getattr(args, "checkpoint_dir", None) or self.resume_dir or f"{self.save_path}/checkpoint"
        self.resumed_from: Checkpoint | None = None
        # What made the run (--algo, env, hyperparameters), kept in its checkpoints for --resume to compare with
        self.run_config: dict[str, Any] = {}
        # The warning for a run on a bundled file's `default` entry (default_settings_note), given once the setup is done
        self.default_settings: str | None = None
        # The step at which Ctrl-C or SIGTERM stopped training (None: it was not), and whether it was SIGTERM
        self.interrupted_at: int | None = None
        self.terminated = False
        # The evaluation keys of a settings file (EVALUATION_KEYS): None where it has none
        self.eval_exploration_rate: float | None = None
        self.eval_env_wrapper: Any = None
        self.final_eval_episodes: int | None = None

    def setup_experiment(self) -> tuple[BaseAlgorithm, dict[str, Any]] | None:
        """
        The zoo's setup; with ``--resume``, the model, replay buffer and env normalisation are the checkpoint's (the
        zoo's own continue-training path loads them), the last stored transitions are cut as truncations, the random
        generators are seeded for the resumed part (:func:`sb3_offon.resume.resumed_seed`), and the evaluation callback
        holds the evaluations so far. A setup that fails (a refused resume, an unknown hyperparameter, a bad value)
        leaves no run folder behind.
        """
        if self.resume_dir is not None:
            self.resumed_from = Checkpoint.latest(self.resume_dir)
            if self.resumed_from is None:
                raise CheckpointError(f"--resume {self.resume_dir}: no checkpoint there (written by --checkpoint-freq)")
            self.trained_agent = str(self.resumed_from.model_path)
            self.continue_training = True
        run_folder_existed = Path(self.save_path).exists()
        try:
            with n_step_reload_unflagged() if self.resumed_from is not None else contextlib.nullcontext():
                results = super().setup_experiment()
        except BaseException as error:
            if not run_folder_existed:
                shutil.rmtree(self.save_path, ignore_errors=True)
            if isinstance(error, ValueError) and type(error) is not HyperparameterError and raised_by_a_constructor(error):
                # What the algorithm refused, in the line the command line prints (sb3_offon.train)
                raise HyperparameterError(f"invalid hyperparameter (--hyperparams or the YAML file): {error}") from error
            raise
        if self.default_settings is not None:
            # After the setup, not where the settings are read: the last thing said before training, and not said at
            # all for a command refused in the setup (an env whose actions the algorithm cannot take)
            warnings.warn(self.default_settings, DefaultHyperparametersWarning, stacklevel=2)
        if results is None or self.resumed_from is None:
            return results
        model, saved_hyperparams = results
        self.resumed_from.prepare(model, self._eval_callback(), self.callbacks)
        return model, saved_hyperparams

    def read_hyperparameters(self) -> tuple[dict[str, Any], dict[str, Any]]:
        """
        The zoo's hyperparameters, checked before anything is made: every key the zoo's or an argument of the algorithm
        (:func:`check_hyperparameter_names`), and with ``--resume`` the algorithm, env, hyperparameters and budget the
        checkpoint was made with (:meth:`check_resumed_run`).
        """
        hyperparams, saved_hyperparams = super().read_hyperparameters()
        check_hyperparameter_names(self.algo, ALGOS.get(self.algo, zoo_utils.ALGOS[self.algo]), hyperparams)
        self.run_config = {
            "algo": ALIASES.get(self.algo, self.algo),
            "env": self.env_name.gym_id,
            "hyperparams": comparable(dict(saved_hyperparams)),
        }
        # -n, else the entry's (the zoo applies it later, in _preprocess_hyperparams)
        budget = self.n_timesteps if self.n_timesteps > 0 else int(hyperparams.get("n_timesteps", 0))
        self.default_settings = default_settings_note(self.config, self.env_name.gym_id, self._is_atari, budget)
        if self.resumed_from is not None:
            self.check_resumed_run(self.resumed_from, budget)
        return hyperparams, saved_hyperparams

    def check_resumed_run(self, checkpoint: Checkpoint, budget: int) -> None:
        """
        :raises CheckpointError: in a line, when the checkpoint was made by another algorithm, on another env, with
            other hyperparameters (each that differs named with both values) or another budget than this command's
        """
        where = f"--resume {self.resume_dir}"
        recorded = checkpoint.run_config
        if not recorded:
            # Made from Python, or before checkpoints recorded what made them: the model's class is all there is
            checkpoint.check_algorithm(zoo_utils.ALGOS[self.algo])
            warnings.warn(f"{where}: the checkpoint does not record the hyperparameters it was made with: not compared")
        else:
            for key, flag in (("algo", "--algo"), ("env", "--env")):
                if recorded.get(key) != self.run_config[key]:
                    raise CheckpointError(
                        f"{where}: the run was made with {flag} {recorded.get(key)}, this command has {flag} "
                        f"{self.run_config[key]}: resume a run with what it was started with"
                    )
            before, now = recorded.get("hyperparams", {}), self.run_config["hyperparams"]
            differences = [
                f"{key} {before.get(key, '(not set)')!r} there, {now.get(key, '(not set)')!r} here"
                for key in sorted({*before, *now})
                if before.get(key) != now.get(key)
            ]
            if differences:
                raise CheckpointError(
                    f"{where}: the run was made with other hyperparameters than this command gives: {'; '.join(differences)}"
                )
        if budget != checkpoint.total_timesteps:
            raise CheckpointError(
                f"{where}: the run was checkpointed with a budget of {checkpoint.total_timesteps} steps, this command "
                f"trains {budget} (-n): a resumed run keeps its budget"
            )

    def _preprocess_hyperparams(self, hyperparams: dict[str, Any]) -> tuple[dict[str, Any], Any, Any, Any]:
        """
        The zoo's preprocessing, after taking out the evaluation keys of a settings file (:data:`EVALUATION_KEYS`:
        ``eval_exploration_rate``, ``eval_env_wrapper``, ``final_eval_episodes``), which are not the algorithm's; and
        an ``ALE/<Game>-v5`` id under an env wrapper made the ``NoFrameskip-v4`` game (:func:`sb3_offon.atari.ale_v5_kwargs`),
        said in one line.
        """
        self.eval_exploration_rate = hyperparams.pop("eval_exploration_rate", None)
        wrapper = hyperparams.pop("eval_env_wrapper", None)
        self.eval_env_wrapper = None if wrapper is None else get_wrapper_class({"env_wrapper": wrapper})
        episodes = hyperparams.pop("final_eval_episodes", None)
        self.final_eval_episodes = None if episodes is None else int(episodes)
        hyperparams, env_wrapper, callbacks, vec_env_wrapper = super()._preprocess_hyperparams(hyperparams)
        if env_wrapper is not None:  # AtariWrapper, on an Atari id
            self.env_kwargs, note = ale_v5_kwargs(self.env_name.gym_id, self.env_kwargs)
            self.eval_env_kwargs = ale_v5_kwargs(self.env_name.gym_id, self.eval_env_kwargs)[0]
            if note is not None:
                warnings.warn(note, AtariSettingsNote, stacklevel=2)
        return hyperparams, env_wrapper, callbacks, vec_env_wrapper

    def create_envs(self, n_envs: int, eval_env: bool = False, no_log: bool = False) -> VecEnv:
        """
        The zoo's envs (training or evaluation), their action space checked against the algorithm's
        (:func:`check_action_space`) as soon as the first is made, before the model: SB3 would refuse it there with
        an assertion's traceback. Evaluation envs are wrapped in the settings' ``eval_env_wrapper`` where they give one
        (the Atari 100k settings: whole games), in place of ``env_wrapper``.

        :param n_envs: the number of envs
        :param eval_env: whether they are for evaluation
        :param no_log: whether to leave out the monitor files
        :return: the vectorised envs
        :raises UnsupportedActionSpaceError: in a line, the envs closed
        """
        training_wrapper = self.env_wrapper
        if eval_env and self.eval_env_wrapper is not None:
            self.env_wrapper = self.eval_env_wrapper
        try:
            env = super().create_envs(n_envs, eval_env=eval_env, no_log=no_log)
        finally:
            self.env_wrapper = training_wrapper
        try:
            check_action_space(self.algo, zoo_utils.ALGOS[self.algo], self.env_name.gym_id, env.action_space)
        except UnsupportedActionSpaceError:
            env.close()
            raise
        return env

    def _eval_callback(self) -> EvalCallback | None:
        """The run's evaluation callback, which the zoo's ``create_callbacks`` adds with ``--eval-freq`` (else None)."""
        return next((callback for callback in self.callbacks if isinstance(callback, EvalCallback)), None)

    def create_callbacks(self) -> None:
        """
        The zoo's callbacks, then (with ``--checkpoint-freq``) a :class:`sb3_offon.resume.RunCheckpoint` after them; for
        an algorithm without the package's checks of non-finite rewards and losses (SB3's DQN, the zoo's others), a
        :class:`sb3_offon.common.non_finite.NonFiniteCheck` before them, so that no checkpoint or best model is written
        after a non-finite reward or loss.
        """
        super().create_callbacks()
        zoo_eval = self._eval_callback()
        if zoo_eval is not None and self.eval_exploration_rate is not None:
            # The settings' evaluation policy (epsilon-greedy at eval_exploration_rate) instead of the zoo's
            self.callbacks[self.callbacks.index(zoo_eval)] = EpsilonGreedyEvalCallback(
                zoo_eval.eval_env,
                exploration_rate=float(self.eval_exploration_rate),
                seed=self.seed,
                callback_on_new_best=zoo_eval.callback_on_new_best,
                best_model_save_path=zoo_eval.best_model_save_path,
                n_eval_episodes=zoo_eval.n_eval_episodes,
                log_path=self.save_path,
                eval_freq=zoo_eval.eval_freq,
            )
        if not issubclass(zoo_utils.ALGOS[self.algo], NonFiniteChecksMixin):
            self.callbacks.insert(0, NonFiniteCheck())
        if self.checkpoint_freq > 0:
            self.callbacks.append(
                RunCheckpoint(
                    self.checkpoint_dir,
                    self.checkpoint_freq,
                    eval_callback=self._eval_callback(),
                    monitor_dir=self.save_path,
                    resumed_from=self.resumed_from,
                    # Where the zoo's continue-training path looks for them (ExperimentManager._maybe_normalize)
                    vec_normalize_path=f"{self.env_name}/vecnormalize.pkl",
                    callbacks=list(self.callbacks),
                    run_config=self.run_config,
                    verbose=self.verbose,
                )
            )

    def _learn_to_budget(self, model: BaseAlgorithm) -> None:
        """
        The zoo's ``learn`` (its logging interval, callbacks, Ctrl-C and clean-up), for the budget or, in a resumed run,
        the steps its budget has left; Ctrl-C is recorded in :attr:`interrupted_at` instead of passed over in silence.

        Repeated rather than called: the zoo's swallows the ``KeyboardInterrupt`` (so that the model trained so far is
        saved after it) and calls ``model.learn(n_timesteps)`` without ``reset_num_timesteps``, and a ``learn`` set on
        the model to change either would be pickled into every checkpoint the model saves.
        """
        kwargs: dict[str, Any] = {}
        if self.log_interval > -1:
            kwargs["log_interval"] = self.log_interval
        elif self.log_interval < -1:
            kwargs["log_interval"] = None
        if self.callbacks:
            kwargs["callback"] = self.callbacks
        if self.algo == "ars" and self.n_envs > 1:
            # As the zoo: ARS evaluates its candidates in parallel envs
            kwargs["async_eval"] = zoo_exp_manager.AsyncEval(
                [lambda: self.create_envs(n_envs=1, no_log=True) for _ in range(self.n_envs)], model.policy
            )
        steps = self.n_timesteps
        if self.resumed_from is not None:
            steps, kwargs["reset_num_timesteps"] = self.n_timesteps - model.num_timesteps, False
        # With checkpoints, SIGTERM waits for the next one (sb3_offon.termination); without, it stops the run as Ctrl-C
        deferred = termination_deferred() if self.checkpoint_freq > 0 else contextlib.nullcontext()
        try:
            with deferred:
                model.learn(steps, **kwargs)
        except KeyboardInterrupt as interruption:
            # The model trained so far is saved, as the zoo does; save_trained_model then raises RunInterrupted
            self.interrupted_at = int(model.num_timesteps)
            self.terminated = isinstance(interruption, Terminated)
        finally:
            if self.callbacks:
                self.callbacks[0].on_training_end()  # the zoo's: closes the progress bar
            try:
                assert model.env is not None
                model.env.close()
            except EOFError:
                pass

    def learn(self, model: BaseAlgorithm) -> None:
        """
        The zoo's training; a resumed run trains the steps its budget has left, its step count going on
        (``reset_num_timesteps=False``), and its monitor files are joined to the checkpoint's. A run that reaches its
        budget removes its checkpoints: they are for runs that did not. So does a run that a callback of its own ended
        on purpose (one whose ``stopped_at`` is set, :class:`sb3_offon.callbacks.StopOnMeanTrainingReward`): it is
        finished, and says so in ``stopped.json`` in its log folder (the step and the callback), which tells it from a
        run cut short by Ctrl-C. A run cut short (Ctrl-C or SIGTERM, in its last rollout too) keeps its checkpoints; the zoo
        saves its model, then :meth:`save_trained_model` raises :class:`RunInterrupted`. With ``final_eval_episodes``, the
        trained model is checkpointed before its games (:meth:`checkpoint_trained`).
        """
        self._learn_to_budget(model)
        if self.resumed_from is not None:
            for name, text in self.resumed_from.monitor_texts.items():
                current = Path(self.save_path) / name
                current.write_text(joined_monitor(text, current.read_text() if current.is_file() else ""))
        stopped_by = [callback for callback in self.callbacks if getattr(callback, "stopped_at", None) is not None]
        if stopped_by:
            record = {"num_timesteps": int(model.num_timesteps), "callback": type(stopped_by[0]).__name__}
            (Path(self.save_path) / STOPPED_FILE).write_text(json.dumps(record, indent=2) + "\n")
        if self.final_eval_episodes and model.num_timesteps >= self.n_timesteps and self.interrupted_at is None:
            self.checkpoint_trained(model)
            self.evaluate_final(model)
        # Stopped at its budget by Ctrl-C or SIGTERM (in its last rollout), a run is not finished: it has its games to play
        finished = model.num_timesteps >= self.n_timesteps or stopped_by
        if self.checkpoint_freq > 0 and finished and self.interrupted_at is None:
            shutil.rmtree(self.checkpoint_dir, ignore_errors=True)

    def checkpoint_trained(self, model: BaseAlgorithm) -> None:
        """
        With checkpoints, one of the trained model before the evaluation after training: a run cut in that evaluation
        (100 Atari games take up to a quarter of an hour) resumes at its budget, trains no further and plays the games,
        instead of training again from its last checkpoint.
        """
        checkpoints = [callback for callback in self.callbacks if isinstance(callback, RunCheckpoint)]
        if checkpoints and checkpoints[0].saved_step != model.num_timesteps:
            checkpoints[0].save()

    def evaluate_final(self, model: BaseAlgorithm) -> None:
        """
        The settings' score after training (``final_eval_episodes`` episodes of one evaluation env, epsilon-greedy at
        ``eval_exploration_rate``, 0 where the settings give none), into ``final_evaluation.npz`` in the run's folder
        (:func:`sb3_offon.evaluation.final_evaluation`), before the checkpoints are removed.
        """
        assert self.final_eval_episodes is not None
        env = self.create_envs(1, eval_env=True)
        try:
            record = final_evaluation(
                model,
                env,
                self.final_eval_episodes,
                float(self.eval_exploration_rate or 0.0),
                self.save_path,
                seed=None if self.seed is None else self.seed + 1,
            )
        finally:
            env.close()
        returns = record["results"]
        print(
            f"Final evaluation: {len(returns)} episodes, mean return {returns.mean():.2f} +/- {returns.std():.2f} "
            f"({record['wall_time_s']:.0f} s)"
        )

    def save_trained_model(self, model: BaseAlgorithm) -> None:
        """
        The zoo's (the model, its replay buffer with ``--save-replay-buffer``, the env's normalisation); for a run that
        Ctrl-C cut short, then :class:`RunInterrupted`: the zoo's ``train()`` calls this last, so the interruption
        reaches the command line once everything the zoo saves is saved.

        :param model: the trained model
        :raises RunInterrupted: when training was interrupted
        """
        super().save_trained_model(model)
        if self.interrupted_at is not None:
            raise RunInterrupted(
                self.interrupted_at,
                self.n_timesteps,
                self.save_path,
                self.checkpoint_dir if self.checkpoint_freq > 0 else None,
                self.checkpoint_freq,
                terminated=self.terminated,
            )


def register() -> None:
    """
    Register the algorithms, their samplers and the bundled hyperparameter files into ``rl_zoo3``.

    Call it before ``rl_zoo3.train.train()`` or ``rl_zoo3.enjoy.enjoy()``: their ``--algo`` choices are read from
    ``ALGOS`` when the argument parser is built. Calling it again does nothing more.
    """
    # Every module's ALGOS is the same dict today; each is updated anyway, in case a zoo release copies it
    for module in (zoo_utils, zoo_train, zoo_exp_manager, zoo_enjoy):
        module.ALGOS.update(ALGOS)
    zoo_hyperparams_opt.HYPERPARAMS_SAMPLER.update(SAMPLERS)
    # Our optuna parameter names are the constructor's: the off-policy converter passes them through
    zoo_hyperparams_opt.HYPERPARAMS_CONVERTER.update({name: convert_offpolicy_params for name in ALGOS})
    zoo_train.ExperimentManager = OffOnExperimentManager  # type: ignore[misc]
    # The zoo evaluates a YAML file's `policy_kwargs` string in the namespace of its exp_manager module (which has
    # `th` and `nn`): the MinAtar entries' "dict(features_extractor_class=MinAtarCNN, ...)" finds the class there
    zoo_exp_manager.MinAtarCNN = MinAtarCNN  # type: ignore[attr-defined]
    zoo_exp_manager.DataEfficientCNN = DataEfficientCNN  # type: ignore[attr-defined]
    # Likewise a `replay_buffer_class` given by name (``--hyperparams replay_buffer_class:PrioritizedOffOnReplayBuffer``)
    for buffer_class in PRIORITIZED_BUFFERS:
        setattr(zoo_exp_manager, buffer_class.__name__, buffer_class)
