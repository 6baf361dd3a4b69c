"""Speed and memory of the GNS family beyond one evaluation: the benchmark CLI (scaling with the particle
count, model comparisons, culling; ``python -m gnsx.perf.benchmark``), training throughput of the Lightning
loop (``python -m gnsx.perf.throughput``), analytic FLOPs and rollout memory tracking. Every inference timing
is :func:`gnsx.evaluation.timing.measure_inference`, the same function the evaluation tables use."""
