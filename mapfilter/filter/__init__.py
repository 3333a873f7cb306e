"""The regularised particle filter: particle state, models, resampling, the step loop."""

import os

# numba's OpenMP threading layer spins idle threads by default (OMP_WAIT_POLICY=active).
# On a shared 2-core machine those spinning threads fight every other process and each
# parallel kernel launch waits for a descheduled thread: a 10k-particle step measured
# 82 ms with spinning and 6 ms with PASSIVE under load ~6. libgomp reads this variable
# once, when numba first starts its thread pool, so it must be set before any parallel
# kernel runs; a value the user set wins.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
