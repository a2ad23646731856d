"""Timings, memory and fault benchmarks, and the import-structure measure."""
