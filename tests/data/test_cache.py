"""The cache of simulated systems: a hit returns the same values, an edit to the system misses."""
import dataclasses

import torch

from msam_torch.data import cache
from msam_torch.data.systems import get_system, measure, multisine


def test_a_second_measure_reads_the_first_and_the_copy_is_the_callers(monkeypatch, tmp_path):
    monkeypatch.setenv("MSAM_CACHE_DIR", str(tmp_path))
    monkeypatch.setattr(cache, "_MEMORY", {})
    system = dataclasses.replace(get_system("msd_quadratic_drag"), samples=200, t_end=4.0)
    first = measure(system)
    assert len(list(tmp_path.glob("*.pt"))) == 1
    first["x"].add_(1.0)  # the caller's copy, not the cache's
    monkeypatch.setattr(cache, "_MEMORY", {})  # a new process: read from the folder
    calls = []
    monkeypatch.setattr("torchdiffeq.odeint", lambda *a, **k: calls.append(1))  # imported where a system is integrated
    second = measure(system)
    assert calls == []
    torch.testing.assert_close(second["x"], first["x"] - 1.0, rtol=0, atol=1e-15)
    assert float(second["x"].abs().max()) > 0.05


def test_a_changed_parameter_input_or_effect_is_another_key():
    base = get_system("msd_quadratic_drag")
    keys = {cache.fingerprint(s) for s in (
        base, dataclasses.replace(base, parameters={**base.parameters, "cq": 0.41}),
        dataclasses.replace(base, inputs={"u": multisine((0.4, 0.7), 2.5)}),
        dataclasses.replace(base, inputs={"u": multisine((0.4, 0.7), 2.6)}),
        get_system("msd_hardening"))}
    assert len(keys) == 5
    assert cache.fingerprint(base) == cache.fingerprint(get_system("msd_quadratic_drag"))


def test_an_empty_cache_setting_writes_nothing(monkeypatch, tmp_path):
    monkeypatch.setenv("MSAM_CACHE_DIR", "")
    monkeypatch.setattr(cache, "_MEMORY", {})
    assert cache.folder() is None
    value = cache.cached(lambda: torch.ones(3), "key")
    assert value.tolist() == [1.0, 1.0, 1.0] and not any(tmp_path.iterdir())
