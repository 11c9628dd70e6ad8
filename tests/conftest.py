from collections.abc import Iterator

import pytest
import torch as th

# One torch thread per process: on a 2-core machine the default (one per core) makes concurrent test processes
# fight over the cores and runs many times slower.
th.set_num_threads(1)


@pytest.fixture(autouse=True)
def ieee_denormals() -> Iterator[None]:
    """
    Every test starts and ends with denormal floats computed as IEEE 754 says: the command line's ``main()``, which some
    tests call in this process, flushes them to zero for the rest of the thread's life (sb3_offon.train).
    """
    th.set_flush_denormal(False)
    yield
    th.set_flush_denormal(False)
