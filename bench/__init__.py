"""Benchmark scripts: each prints its numbers and writes its page of docs/results/ (run `python bench/NAME.py -h`).

Scripts share code by importing one another through this package (`from bench.bench_seg import ...`)."""
