"""Structure-aware fuzzing of every input splitrender parses (issue 15).

Each case starts from a small *valid* input generated here (a stream packet and file, a
recording, a dataset folder, a glTF/GLB model, a scene description, a head trace, a command
line), applies a mutation that knows the input's structure (truncation, bit flips, length and
count fields, wrong versions, reordered records, values swapped for boundary values and wrong
types) and runs the parser in a forked child under a memory limit. The outcome is classified as
one of :class:`~tests.fuzz.harness.Outcome`; only "specific error" and "accepted" are good.

Run the long profile and rewrite docs/fuzz-results.md with::

    PYTHONPATH=python python -m tests.fuzz --cases 2400 --seed 1 --out docs/fuzz-results.md

``tests/test_fuzz.py`` runs a fixed-seed subset in CI, then the hand-picked cases of
``tests/fuzz/pinned.py`` (one per input check that matters, each required to end as the specific
error it pins), and draws a fresh seed under ``pytest -m fuzz``.
"""

import os

# The fork server forks a process that has imported numpy: OpenBLAS must not have started its
# thread pool (a forked child would inherit its locks without its threads), so it is held to
# one thread before numpy is first imported (the harness checks that it runs single-threaded).
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")
