"""
Unquoted string values for the zoo's ``key:value`` options (``--hyperparams``, ``--env-kwargs``, ``--eval-env-kwargs``).

rl-baselines3-zoo parses each value with ``eval`` (``rl_zoo3.utils.StoreDict``), so a string has to be quoted twice:
``--hyperparams "mc_mixing:'convex'"``, while ``mc_mixing:convex`` fails with ``NameError: name 'convex' is not
defined``. :class:`TolerantStoreDict` is the zoo's action with two additions, applied before the zoo evaluates:

- a value that is a bare word (a Python identifier) and that the zoo cannot evaluate (``NameError``) is that word as a
  string: ``mc_mixing:convex`` gives ``"convex"``;
- a bare word that is one of the string choices of our algorithms' options (:data:`STRING_OPTIONS`) is that string
  even when it evaluates or is a Python keyword: ``mc_mixing:max`` gives ``"max"``, where the zoo would give Python's
  builtin ``max``, and ``mc_mixing:lambda`` gives ``"lambda"``, where the zoo's ``eval`` would fail.

Everything else is evaluated by the zoo itself, as before: numbers, lists, dicts, ``"dict(net_arch=[64])"``, quoted
strings (``"'lin_1e-3'"``), names the zoo knows (``True``, ``nn.ReLU``, ...), and the errors of what does not evaluate.
"""

import argparse
import keyword
from collections.abc import Sequence
from types import ModuleType
from typing import Any

import rl_zoo3.enjoy as zoo_enjoy
import rl_zoo3.train as zoo_train
from rl_zoo3.utils import StoreDict

from sb3_offon.common.offon_model import MC_TRUNCATION_OPTIONS
from sb3_offon.offon_dqn.offon_dqn import LOSS_FUNCTIONS, MC_MIXING_OPTIONS, SARSA_TARGET_OPTIONS
from sb3_offon.offon_qrdqn.quantile_lambda_returns import LAMBDA_FORMS

# The string-valued options of OffOnDQN and its variants, and their choices. "max" is also a Python builtin: without
# this table ``mc_mixing:max`` would evaluate to the function
STRING_OPTIONS: dict[str, tuple[str, ...]] = {
    "mc_mixing": MC_MIXING_OPTIONS,
    "sarsa_target": SARSA_TARGET_OPTIONS,
    "mc_truncation": MC_TRUNCATION_OPTIONS,
    "loss": tuple(LOSS_FUNCTIONS),
    "lambda_form": LAMBDA_FORMS,
}


class TolerantStoreDict(StoreDict):
    """
    The zoo's ``StoreDict`` argparse action (``key:value`` pairs into a dict), taking bare words as strings.

    See the module's documentation for the rules. A subclass, so that whatever tests ``isinstance(action, StoreDict)``
    still sees the zoo's action.
    """

    def __call__(
        self, parser: argparse.ArgumentParser, namespace: argparse.Namespace, values: Any, option_string: str | None = None
    ) -> None:
        """
        Store ``values`` (``key:value`` strings) as a dict in ``namespace``, bare words quoted first.

        :param parser: the parser
        :param namespace: where the dict is stored (under this action's ``dest``)
        :param values: the ``key:value`` strings given to the option
        :param option_string: the option's flag (``--hyperparams``)
        """
        quoted = [self._quote_bare_word(parser, argument) for argument in values]
        super().__call__(parser, namespace, quoted, option_string)

    def _quote_bare_word(self, parser: argparse.ArgumentParser, argument: str) -> str:
        # Split as the zoo does: the key ends at the first colon
        key, separator, value = argument.partition(":")
        word = value.strip()
        # Anything that is not a single name is left to the zoo
        if not separator or not word.isidentifier():
            return argument
        # One of our string choices, even a builtin's name (max) or a keyword (lambda)
        if word in STRING_OPTIONS.get(key, ()):
            return f"{key}:{word!r}"
        # True, False, None and the other keywords are left to the zoo
        if keyword.iskeyword(word):
            return argument
        try:
            # The zoo's own evaluation of this one pair, in its own namespace, so that a name it knows (``th``, ``nn``,
            # a builtin, ...) keeps its meaning. Evaluating a bare name has no side effect
            StoreDict.__call__(self, parser, argparse.Namespace(), [argument])
            return argument
        except NameError:
            return f"{key}:{word!r}"


def use_tolerant_store_dict(modules: Sequence[ModuleType] = (zoo_train, zoo_enjoy)) -> None:
    """
    Make the zoo's command lines parse their ``key:value`` options with :class:`TolerantStoreDict`.

    The zoo builds its parser inside ``train()``/``enjoy()``, from the module's global ``StoreDict``: replacing that
    global before the call is enough, and leaves ``rl_zoo3.utils.StoreDict`` itself alone. Calling it again does nothing
    more.

    :param modules: the zoo modules whose parser should use it (``rl_zoo3.train`` and ``rl_zoo3.enjoy`` by default)
    """
    for module in modules:
        module.StoreDict = TolerantStoreDict  # type: ignore[attr-defined]
