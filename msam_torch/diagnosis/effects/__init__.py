"""Candidate effects of a diagnosis: hypotheses fitted as a batch, their bootstrap trials, several
effects in turn and the adapted structure written as a starting model."""
