"""SmokeSeer trainer.

Importing the package sets ``OMP_WAIT_POLICY=PASSIVE`` unless the environment already names a
policy. Why: torch's CPU ops and the compiled rasterizer run short OpenMP regions, and by default
libgomp's idle threads spin for a while after each one. When the cores are shared (another run,
a harness worker, a test suite), a spinning thread takes the core its descheduled peer needs to
finish the region: a two-thread demo run took 271 s instead of 25 s at load 5.7, with 94 % of
its samples in libgomp's wait loop (docs/rasterizer.md, "Threads"). libgomp reads the variable
when it loads, so this must happen before torch is imported; the CLIs import this package
first, and it is inherited by the processes they start.
"""
import os

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
