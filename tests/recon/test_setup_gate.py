"""The set-up gate of local multi-block runs: held through a block's set-up, lifted while DAO
estimates the wavefront of a small block (so one block's DAO does not idle the other workers),
kept through a large block's DAO (whose memory grows with its window) unless the free memory
holds two of them."""

import threading
from types import SimpleNamespace

import numpy as np
import pytest

from metasensor.dao import estimate
from metasensor.recon import block


def _free(gate) -> bool:
    """Whether another block could take the gate now (taken and given back at once)."""
    if gate.acquire(blocking=False):
        gate.release()
        return True
    return False


def _recording_dao(gate, seen):
    """A stand-in for ``run_dao`` that notes whether the gate is free while it runs."""
    def fake_dao(window, cfg, options, **kw):
        seen["during_dao"] = _free(gate)
        return SimpleNamespace(zernike=np.r_[0, 0, 0, 0.3], history=[0.3], fits=[0.05])
    return fake_dao


def test_the_gate_is_lifted_during_dao_and_held_again_for_the_bank(monkeypatch, bank_task):
    gate = threading.Semaphore(1)
    gate.acquire()  # as reconstruct_block holds it from the block's start
    seen = {}

    def fake_bank(cfg, zernike, device):
        seen["during_bank"] = _free(gate)
        return np.zeros((cfg.nnum, cfg.nnum, 3, 3), np.float32)

    monkeypatch.setattr(estimate, "run_dao", _recording_dao(gate, seen))
    window = np.ones((15, 15, 8, 8), np.float32)
    bank, merged, history, est, fit = block._bank(bank_task(gate, fake_bank), window)
    assert seen == {"during_dao": True, "during_bank": False}
    assert not _free(gate)  # held again: released at the solver's first step
    assert history == [0.3] and fit == 0.05 and merged[3] == np.float32(0.3)


@pytest.mark.parametrize("room_gb, lifted", [(0.5, False), (64.0, True)])
def test_a_large_block_keeps_the_gate_through_dao_unless_memory_holds_two(
        monkeypatch, bank_task, room_gb, lifted):
    # A window above DAO_UNGATED_SAMPLES: its DAO keeps the gate where the free memory does not
    # hold two such DAOs, and runs outside it where it does.
    from metasensor.io import memory

    gate = threading.Semaphore(1)
    gate.acquire()
    seen = {}
    monkeypatch.setattr(estimate, "run_dao", _recording_dao(gate, seen))
    monkeypatch.setattr(memory, "memory_room", lambda: int(room_gb * 1e9))
    side = int(np.sqrt(block.DAO_UNGATED_SAMPLES)) + 1
    window = np.ones((15, 15, side, side), np.float32)
    block._bank(bank_task(gate, lambda cfg, z, dev: np.zeros((15, 15, 3, 3), np.float32)),
                window)
    assert seen == {"during_dao": lifted}
    assert not _free(gate)


def test_the_gate_is_taken_back_when_dao_fails(monkeypatch, bank_task):
    gate = threading.Semaphore(1)
    gate.acquire()

    def failing_dao(*args, **kw):
        raise RuntimeError("no wavefront")

    monkeypatch.setattr(estimate, "run_dao", failing_dao)
    with pytest.raises(RuntimeError, match="no wavefront"):
        block._bank(bank_task(gate), np.ones((15, 15, 8, 8), np.float32))
    assert not _free(gate)  # reconstruct_block's own release then frees it once
