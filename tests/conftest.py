"""Fixtures shared by several test modules."""
import pytest
import torch


@pytest.fixture(scope="module")
def one_thread():
    """One torch thread for a whole module: tiny tensors gain nothing from a second intra-op thread, which only adds
    synchronisation and thrashes on a busy 2-core CI box. Restores the previous setting afterwards.
    Use with ``pytestmark = pytest.mark.usefixtures("one_thread")``: the suite's only one-thread switch (no copies
    in test modules, and no ``torch.set_num_threads`` at import, which would leak into every later module)."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)
