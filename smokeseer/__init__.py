"""SmokeSeer trainer.

Importing the package sets ``GOMP_SPINCOUNT=10000`` unless the environment already sets it or
``OMP_WAIT_POLICY``. Why: torch's CPU ops and the compiled rasterizer run many short OpenMP
regions, and libgomp's idle threads spin for up to 300,000 rounds (milliseconds) after each one
before they sleep. When the cores are shared (another run, a harness worker, a test suite), a
spinning thread takes the core its descheduled peer needs to finish the region: a two-thread
300 + 300 iteration demo run took 271 s instead of 25 s at load 5.7, with 94 % of its samples
in libgomp's wait loop. 10,000 rounds bridge the gaps between back-to-back regions, so a quiet
machine keeps its speed (where sleeping at once, ``OMP_WAIT_POLICY=PASSIVE``, cost a third
more wall time). Measurements in docs/rasterizer.md ("Threads"). libgomp reads the variable
when it loads, so this must happen before torch is imported: the CLIs import this package
first, and the processes they start inherit it.
"""
import os

if "OMP_WAIT_POLICY" not in os.environ:
    os.environ.setdefault("GOMP_SPINCOUNT", "10000")
