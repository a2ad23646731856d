"""The reproduction experiments and benchmarks (see experiments/README.md); run each from the repository
root as a module: ``python -m experiments.<folder>.<script>``."""
