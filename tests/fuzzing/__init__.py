"""Property-based fuzzing of planet-intersect (hypothesis), crash-safe.

* ``strategies.py``: hypothesis strategies producing fuzz cases (plain dicts)
* ``ops.py``: what each case does and the properties of its result (in the worker)
* ``worker.py``: the worker process; a segfault or hang kills only it
* ``harness.py``: the parent side: worker management, judgement, reproducers
* ``runner.py``: hypothesis runs over every target, for pytest and the long mode
* ``bulk.py``: the bulk mode: the same cases drawn with numpy in the worker, in
  batches, with the same checks and judgement (README.md: the 1,000,000-call run)

``tests/test_fuzz.py`` runs a CI-sized budget (hypothesis, and 20,000 bulk
calls); ``./dev fuzz --minutes N`` (``python -m tests.fuzzing``) the long mode;
``./dev fuzz --bulk --calls N [--jobs 2]`` the bulk mode.
"""
