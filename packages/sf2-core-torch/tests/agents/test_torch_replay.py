"""The torch agents' replay buffer (sf2_torch/agents/replay.py): a ring of the last `capacity`
transitions, uniform draws from the filled part, one seed's generator deciding every draw, a state dict
that restores contents and write position, and no device value read to the host on the way (on a GPU an
`.item()` waits for all the work queued before it)."""

from __future__ import annotations

import torch
from sf2_torch.agents.replay import ReplayBuffer, to_batch
from tensordict import TensorDict


def _transitions(start, n):
    """n transitions whose every field holds its number, start … start + n − 1."""
    v = torch.arange(start, start + n, dtype=torch.float32)[:, None]
    nxt = TensorDict({"observation": v.repeat(1, 3), "reward": v, "done": v < 0, "terminated": v < 0,
                      "truncated": v < 0}, [n])
    return TensorDict({"observation": v.repeat(1, 3), "action": v, "next": nxt}, [n])


def _filled(seed=0, capacity=10, batches=4, n=4):
    rb = ReplayBuffer(capacity, "cpu", torch.Generator().manual_seed(seed))
    for b in range(batches):
        rb.insert(_transitions(b * n, n))
    return rb


def test_the_ring_keeps_the_last_capacity_transitions_and_draws_only_them():
    rb = _filled()   # 16 transitions into 10 slots: 6 … 15 remain
    assert rb.size() == 10
    drawn = to_batch(rb.sample(2000)).obs[:, 0]
    assert set(drawn.tolist()) == set(range(6, 16))
    counts = torch.bincount(drawn.long() - 6, minlength=10).float()
    assert counts.min() > 2000 / 10 * 0.7 and counts.max() < 2000 / 10 * 1.3   # uniform, ±30% of 200


def test_the_seeds_generator_decides_every_draw():
    a, b, c = _filled(seed=3), _filled(seed=3), _filled(seed=4)
    x, y, z = (to_batch(r.sample(64)).obs for r in (a, b, c))
    assert torch.equal(x, y) and not torch.equal(x, z)


def test_the_state_dict_restores_contents_and_write_position():
    rb = _filled()
    fresh = ReplayBuffer(10, "cpu", torch.Generator().manual_seed(0))
    fresh.load_state_dict(rb.state_dict())
    assert fresh.size() == 10
    for r in (rb, fresh):
        # slots 0–5 hold 10–15 and slots 6–9 hold 6–9; the next write goes to slots 6, 7, 8
        r.insert(_transitions(100, 3))
    stored = [sorted(r.buffer.storage[:10]["observation"][:, 0].tolist()) for r in (rb, fresh)]
    assert stored[0] == stored[1] == [9.0, 10.0, 11.0, 12.0, 13.0, 14.0, 15.0, 100.0, 101.0, 102.0]


def test_a_state_loaded_onto_another_device_restores_and_keeps_the_generator():
    """A checkpoint restored with `map_location` set to a GPU holds TorchRL's copy of the generator state
    there, and a generator takes only a CPU byte tensor; that copy is not read (the `meta` device stands
    in for the GPU here). The buffer keeps drawing from the seed's own generator."""
    rb = _filled()
    state = rb.state_dict()
    rng_state, rng_device = state["_rng"]
    state["_rng"] = (rng_state.to("meta"), rng_device)
    generator = torch.Generator().manual_seed(0)
    fresh = ReplayBuffer(10, "cpu", generator)
    fresh.load_state_dict(state)
    assert fresh.size() == 10 and fresh.buffer._rng is generator
    generator.set_state(rb.generator.get_state())
    assert torch.equal(to_batch(fresh.sample(64)).obs, to_batch(rb.sample(64)).obs)


def test_inserting_and_drawing_read_no_value_to_the_host(monkeypatch):
    """TorchRL's default storage read its last written index with `.item()` at every insert; with
    `compilable=True` (replay.py) nothing on this path does."""
    rb = _filled()
    calls, real = [], torch.Tensor.item

    def item(self):
        calls.append(tuple(self.shape))
        return real(self)

    monkeypatch.setattr(torch.Tensor, "item", item)
    for b in range(5):
        rb.insert(_transitions(50 + 4 * b, 4))
        rb.sample(32)
    assert calls == []
