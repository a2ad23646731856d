import os
import shutil
import tempfile

import pytest
import torch


@pytest.fixture(autouse=True)
def _seed_and_guard_globals():
    """Seed every test and fail any test that changes torch's global default dtype."""
    torch.manual_seed(0)
    dtype = torch.get_default_dtype()
    yield
    assert torch.get_default_dtype() == dtype, "a test changed torch's default dtype"


def pytest_configure(config):
    """The allocator setting the command-line tool runs under (msam_torch.engine.allocator), and a
    cache folder of the session's own (msam_torch.data.cache), for it and the commands it starts."""
    from msam_torch.engine.allocator import keep_freed_memory

    keep_freed_memory()
    config._msam_cache = tempfile.mkdtemp(prefix="msam-cache-")
    os.environ["MSAM_CACHE_DIR"] = config._msam_cache


def pytest_unconfigure(config):
    shutil.rmtree(getattr(config, "_msam_cache", ""), ignore_errors=True)
