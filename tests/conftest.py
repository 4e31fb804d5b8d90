"""Settings of the whole test session (loaded before every test directory's own conftest).

Numba's parallel kernels run on GNU OpenMP here (Numba's "omp" threading layer). The README's test command runs
one pytest-xdist worker per core, and each worker's kernels start a thread per core, so the cores are
oversubscribed; libgomp's default wait policy then keeps idle threads spinning while the other worker's threads
wait for the core. Passive waiting (threads sleep between parallel regions) is set here, before any kernel
loads libgomp (it reads the variable once, when it is loaded); a value set by the caller is kept. It changes the
tests' timing only, not their results (the parallel kernels are bitwise independent of the thread count, see
``tests/hair/test_drape.py::test_parallel_kernels_reproduce_the_serial_ones_bitwise``).
Measured (twenty-eighth session of issue 10), 2 cores: the whole suite (`-n 2`) 341 s against 660 s; that test's
80 steps with another process busy on the cores, 3.5–4.8 s against 14–30 s. A single process on a quiet machine
runs as fast either way (the reference drape step 1.05–1.08 s against 1.04–1.08 s), with less CPU time.
"""

import os

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
