"""Suites of generated and simulated cases: the zoo, withheld effects, noise, derivative windows, presets."""
