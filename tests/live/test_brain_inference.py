"""The live brains' numpy inference (:mod:`bptsb_ros.live.inference`) and the live body's compiled one-body step
(:mod:`bptsb_ros.body.live_step`) against the torch code the offline simulation and training run: the same values
(float64 brains to 1e-12, the SWG table and the body step bit for bit), and the spring lengths a feedback brain
computes from published positions equal to the body's own."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from bptsb_ros.agent import brain_forces, build_agent
from bptsb_ros.config import validate


def _agent(task: str, **extra):
    cfg = {"task": task, "seed": 4, "dtype": "float64", **extra}
    agent = build_agent(validate(cfg))
    for module in agent.modules().values():  # frozen, as the nodes hold them
        module.requires_grad_(False)
    return agent


@pytest.mark.parametrize("brain_type", ["mlp", "lil"])
def test_force_map_equals_brain_forces(brain_type):
    from bptsb_ros.live.inference import ForceMap

    agent = _agent("narma", brain={"type": brain_type})
    if brain_type == "mlp":  # non-zero biases, so that a missing bias term would show
        with torch.no_grad():
            for layer in agent.brain.layers:
                layer.bias.copy_(0.3 * torch.randn(layer.bias.shape, dtype=torch.float64,
                                                   generator=torch.Generator().manual_seed(1)))
    forces = ForceMap(agent)
    cmp = agent.body.cmp_local
    for u in (-3.0, 0.0, 0.37, 12.5):  # negative inputs make the ReLUs cut
        want = brain_forces(agent, torch.tensor([u], dtype=torch.float64)).numpy()
        got = forces(np.array([u]))
        np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12)
        assert got.shape == (agent.body.n_movable, 2) and not got[cmp].any()
    assert np.abs(forces(np.array([12.5]))).max() > 0.1  # the brain does something


def test_feedback_map_equals_the_layer_and_its_gain():
    from bptsb_ros.live.inference import FeedbackMap

    agent = _agent("lissajous")
    layer, base = agent.feedback, agent.body.l
    rng = np.random.default_rng(2)
    layer.load_fit(0.05 * rng.standard_normal(tuple(layer.weight.shape)))
    fmap = FeedbackMap(layer, base)
    for _ in range(5):
        s = base.numpy() * (1 + 0.1 * rng.standard_normal(base.numel()))
        want = layer.rest_length_from_features(base, torch.from_numpy(s).unsqueeze(0))[0].numpy()
        np.testing.assert_allclose(fmap(s), want, rtol=1e-12, atol=0)
        half = base.numpy() + 0.5 * (want - base.numpy())
        np.testing.assert_allclose(fmap(s, gain=0.5), half, rtol=1e-12, atol=0)
    driven = layer.driven.numpy()
    if not driven.all():  # undriven springs keep their rest length exactly
        assert np.array_equal(fmap(s)[~driven], base.numpy()[~driven])


def test_swg_table_is_the_offline_function_at_every_step():
    from bptsb_ros.live.inference import SWG_BLOCK, SwgTable
    from bptsb_ros.sim.rollout import swg_rest_lengths

    agent = _agent("lissajous")
    table = SwgTable(agent.body, agent.brain)
    steps = [0, 1, SWG_BLOCK - 1, SWG_BLOCK, 5 * SWG_BLOCK + 17, 3]  # across blocks, and back
    want = swg_rest_lengths(agent.body, agent.brain, 0, 6 * SWG_BLOCK).numpy()
    for k in steps:
        assert np.array_equal(table(k), want[k])
    assert len(table.blocks) <= 2


def test_spring_lengths_from_positions_are_the_bodys_bit_for_bit():
    from bptsb_ros.live.feedback_loop import spring_lengths

    agent = _agent("lissajous")
    body = agent.body
    state = body.initial_state(1, displacement=0.05 * torch.randn(1, body.n_movable, 2, dtype=torch.float64,
                                                                generator=torch.Generator().manual_seed(3)))
    for _ in range(20):
        state = body.step(state, body.l * 1.05)
    full = body.full_positions(state.r)[0].numpy()
    got = spring_lengths(full, np.asarray(body.topology.springs), np.dtype("float64"))
    assert np.array_equal(got, state.length[0].numpy())
    # a hand value: a 3-4-5 triangle
    assert spring_lengths(np.array([[0.0, 0.0], [3.0, 4.0]]), np.array([[0, 1]]), np.dtype("float64"))[0] == 5.0


def test_the_compiled_live_step_is_msdn_step_and_judges_its_state():
    from bptsb_ros.body.live_step import BROKEN, RUNAWAY, SOUND, LiveStep, soundness

    agent = _agent("lissajous")
    body = agent.body
    step = LiveStep(body)
    state = body.initial_state(1)
    rng = np.random.default_rng(5)
    for k in range(30):
        rest = body.l.numpy() * (1 + 0.05 * rng.standard_normal(body.topology.n_springs))
        force = None if k % 3 else rng.standard_normal((body.n_movable, 2))
        want = body.step(state, torch.from_numpy(rest), None if force is None else torch.from_numpy(force))
        got, code = step(state, rest, force)
        assert code == SOUND and got.step == want.step == k + 1
        for name in ("r", "v", "a", "length"):
            assert np.array_equal(getattr(got, name).numpy(), getattr(want, name).numpy()), (k, name)
        state = got
    r, v, a = (np.zeros((1, 3, 2)) for _ in range(3))
    assert soundness(r, v, a, 10.0, 0.01) == SOUND
    for bad in (np.nan, np.inf):
        broken = r.copy()
        broken[0, 1, 0] = bad
        assert soundness(broken, v, a, 10.0, 0.01) == BROKEN
        assert soundness(r, v, broken, 10.0, 0.01) == BROKEN
    far = r.copy()
    far[0, 2, 1] = -10.5
    assert soundness(far, v, a, 10.0, 0.01) == BROKEN and soundness(far, v, a, 10.5, 0.01) == SOUND
    fast = v.copy()
    fast[0, 0, 0] = 1001.0  # |v|·dt = 10.01 m > 10 m
    assert soundness(r, fast, a, 10.0, 0.01) == RUNAWAY
    fast[0, 0, 0] = 999.0
    assert soundness(r, fast, a, 10.0, 0.01) == SOUND
    hard = a.copy()
    hard[0, 1, 1] = -1.1e5  # |a|·dt² = 11 m
    assert soundness(r, v, hard, 10.0, 0.01) == RUNAWAY


def test_a_body_on_the_torch_backend_has_no_compiled_live_step():
    from bptsb_ros.body.live_step import LiveStep

    agent = _agent("lissajous", training={"backend": "torch"})
    with torch.no_grad(), pytest.raises(ValueError, match="numba kernel"):
        LiveStep(agent.body)
