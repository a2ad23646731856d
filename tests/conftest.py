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
    """The allocator setting the command-line tool runs under (msam_torch.engine.allocator)."""
    from msam_torch.engine.allocator import keep_freed_memory

    keep_freed_memory()
