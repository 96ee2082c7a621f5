"""On top of the data flow: the metrics (:mod:`.metrics`), the paper's experiments
(:mod:`.experiments`), the demo (:mod:`.demo`), the benchmarks (:mod:`.bench`,
:mod:`.bench_codec`) and the encode/play/score pipeline they share (:mod:`.pipeline`).

Only :mod:`.metrics` is imported here; the rest load when used (they pull in plotting and video
libraries)."""

from splitrender.evaluation import metrics

__all__ = ["metrics"]
