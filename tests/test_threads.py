"""One intra-op thread for a block of CPU work, in the calling thread only
(:func:`metasensor.backend.one_thread_here`): other threads, threads started meanwhile and the
caller afterwards keep torch's setting."""

import threading

import pytest
import torch

from metasensor.backend import one_thread_here


@pytest.fixture
def two_threads():
    old = torch.get_num_threads()
    torch.set_num_threads(2)
    yield
    torch.set_num_threads(old)


def _count_in_new_thread(body=None) -> int:
    seen = []

    def run():
        if body is None:
            seen.append(torch.get_num_threads())
        else:
            with body():
                seen.append(torch.get_num_threads())

    t = threading.Thread(target=run)
    t.start()
    t.join()
    return seen[0]


def test_one_thread_here_limits_the_calling_thread_only(two_threads):
    with one_thread_here("cpu"):
        inside = torch.get_num_threads()
        started_inside = _count_in_new_thread()
        x = torch.arange(200_000, dtype=torch.float32)
        total = float((x * 2).sum())
    assert (inside, started_inside, torch.get_num_threads()) == (1, 2, 2)
    assert _count_in_new_thread() == 2
    assert total == float((x * 2).sum())
    # a thread whose first torch call is inside the block is limited too
    assert _count_in_new_thread(one_thread_here) == 1


def test_one_thread_here_restores_on_an_exception_and_skips_other_devices(two_threads):
    with pytest.raises(KeyError), one_thread_here(None):
        assert torch.get_num_threads() == 1
        raise KeyError("inside")
    assert torch.get_num_threads() == 2
    with one_thread_here(torch.device("meta")):
        assert torch.get_num_threads() == 2
