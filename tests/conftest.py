import torch as th

# One torch thread per process: on a 2-core machine the default (one per core) makes concurrent test processes
# fight over the cores and runs many times slower.
th.set_num_threads(1)
