"""Property-based fuzzing of planet-intersect (hypothesis), crash-safe.

* ``strategies.py``: hypothesis strategies producing fuzz cases (plain dicts)
* ``ops.py``: what each case does and the properties of its result (in the worker)
* ``worker.py``: the worker process; a segfault or hang kills only it
* ``harness.py``: the parent side: worker management, judgement, reproducers
* ``runner.py``: hypothesis runs over every target, for pytest and the long mode

``tests/test_fuzz.py`` runs a CI-sized budget; ``./dev fuzz --minutes N``
(``python -m tests.fuzzing``) the long mode.
"""
