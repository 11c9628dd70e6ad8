"""
A one-line error, instead of a traceback, when the command line runs without its optional ``zoo`` dependencies.

``sb3_offon.train`` and ``sb3_offon.enjoy`` (and their console scripts ``sb3-offon-train``/``sb3-offon-enjoy``, which
``pip install sb3-offon`` always creates) run through rl-baselines3-zoo, which only the ``zoo`` extra brings
(``pip install -e ".[zoo]"`` in a clone, ``pip install "sb3-offon[zoo]"`` from an index). This module imports nothing
outside the standard library, so that it works precisely when the zoo is missing.
"""

from collections.abc import Iterator
from contextlib import contextmanager

# The top-level modules of the ``zoo`` extra, and those rl_zoo3 imports when it starts (installed with it): a missing
# one means the extra is not (fully) installed. Any other missing module, our own code's included, is a real bug
# and keeps its traceback.
ZOO_MODULES = frozenset({"rl_zoo3", "optuna", "requests", "sb3_contrib", "huggingface_sb3", "huggingface_hub"})

# Both forms: the package is installed from a clone of its source today (pip install -e ".[zoo]" in its folder), and
# from an index once it is published there
INSTALL_HINT = 'pip install -e ".[zoo]" in a clone of the source, or pip install "sb3-offon[zoo]"'


@contextmanager
def zoo_required() -> Iterator[None]:
    """
    Turn a missing module of the ``zoo`` extra, imported within the block, into a one-line error and exit status 1.

    Wrap only the imports of the zoo-dependent code: an error raised by the command itself is not a missing extra.

    :raises SystemExit: when a package of :data:`ZOO_MODULES` cannot be imported (its message goes to stderr)
    """
    try:
        yield
    except ModuleNotFoundError as error:
        missing = error.name or ""
        # An absent package is reported by its top-level name even when a submodule was imported; a dotted name
        # means the package is there and one of its files is not found: a broken install, not a missing extra
        if missing not in ZOO_MODULES:
            raise
        # ``from None``: the message is the whole report, the chained traceback would only bury it
        raise SystemExit(
            f"error: the sb3-offon command line needs the optional 'zoo' dependencies (module '{missing}' is missing):"
            f" {INSTALL_HINT}"
        ) from None
