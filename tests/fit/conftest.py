"""Fit tests run torch single-threaded: the tensors are small, and on a shared (oversubscribed)
machine torch's OpenMP thread pool turns every small op into a multi-millisecond stall."""
import pytest
import torch


@pytest.fixture(autouse=True)
def _single_thread():
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)
