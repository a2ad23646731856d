"""The allocator setting (msam_torch.engine.allocator) keeps a step's memory in the process."""
import platform
import resource

import pytest
import torch

from msam_torch.engine.allocator import keep_freed_memory
from msam_torch.engine.candidates import enumerate_choices
from msam_torch.engine.step import evaluate, step
from msam_torch.engine.values import State, StepOptions
from tests.helpers import equation_data

pytestmark = pytest.mark.skipif(platform.libc_ver()[0] != "glibc", reason="mallopt is glibc's")


def test_steps_reuse_freed_memory_instead_of_faulting_it_in_again():
    assert keep_freed_memory()
    data, theta, theta_fixed, _ = equation_data("harmonic", normalize="rms")
    trials = 64  # (64, 4, 1000, 2) float64: 4 MiB per column tensor, 1024 pages
    data = data.expand_trials(trials)
    selection = data.select(enumerate_choices(2, 2))
    options = StepOptions(scaling="gauss_newton", step_size="one", theta="varpro")
    shape = (trials, 4)
    state = State(torch.zeros(shape + (2,), dtype=torch.float64), theta.expand(shape + (2,)),
                  theta_fixed.expand(shape + (1,)), torch.zeros(shape, dtype=torch.bool))
    current = evaluate(selection, state, options)
    for _ in range(2):  # the heap grows to the step's working set once
        state = step(selection, state, current, options, conditions=False).state
        current = evaluate(selection, state, options)
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    for _ in range(5):
        state = step(selection, state, current, options, conditions=False).state
        current = evaluate(selection, state, options)
    per_step = (resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before) / 5
    assert per_step < 1024, per_step  # without the setting: ~3700; one fresh 4 MiB tensor alone faults 1024 pages
