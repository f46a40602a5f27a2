"""MNIST drawing core: the loss, the gradient to the brain (finite differences), label maps, readout states."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from finite_differences import fd_relative_error

from bptsb_ros.tasks.digits import load_targets
from bptsb_ros.tasks.drawing import (
    DigitTargets,
    ImageToBody,
    SystemSpec,
    joined_to_cmp,
    label_maps,
    load_system,
    save_system,
)
from bptsb_ros.tasks.readout import ReadoutSpec, ReadoutSystem

F64 = torch.float64


def small_system(brain: str = "mlp", nodes: int = 17, seed: int = 0) -> ImageToBody:
    return ImageToBody(SystemSpec(brain=brain, nodes=nodes, dtype="float64"), seed)


def images(n: int, seed: int = 1) -> torch.Tensor:
    return torch.rand(n, 784, generator=torch.Generator().manual_seed(seed), dtype=F64)


def test_errors_match_a_hand_computation():
    tg = DigitTargets(dtype=F64)
    targets = load_targets()
    rng = np.random.default_rng(0)
    drawing = rng.normal(0, 0.1, (3, tg.t_max + 1, 2))
    labels = np.array([1, 8, 7])
    got = tg.errors(torch.as_tensor(drawing), torch.as_tensor(labels)).numpy()
    for b, lab in enumerate(labels):
        t = targets[lab]
        want = np.mean((drawing[b, : len(t)] - t) ** 2)  # mean over the target's steps and both coordinates
        assert got[b] == pytest.approx(want, rel=1e-12)
    every = tg.all_errors(torch.as_tensor(drawing)).numpy()
    np.testing.assert_allclose(every[np.arange(3), labels], got, rtol=1e-12)
    # a drawing that is exactly digit 4's target: error 0 against 4, and 4 is its nearest target
    exact = torch.as_tensor(tg.padded[4:5].numpy())
    assert float(tg.errors(exact, torch.tensor([4]))) == 0.0 and int(tg.all_errors(exact).argmin()) == 4
    with pytest.raises(ValueError, match="shorter than"):
        tg.errors(torch.zeros(1, 50, 2, dtype=F64), torch.tensor([8]))


def test_cmp_starts_at_rest_and_the_brain_places_the_others():
    system = small_system("lil")
    disp = system.displacement(images(4))
    assert disp.shape == (4, system.body.n_movable, 2)
    assert torch.all(disp[:, system.cmp] == 0) and torch.all(disp[:, system.driven].abs().sum((1, 2)) > 0)
    drawing = system.draw(images(4), 20)
    assert drawing.shape == (4, 21, 2) and torch.all(drawing[:, 0] == 0)


@pytest.mark.parametrize("brain", ["lil", "mlp"])
def test_drawing_gradient_reaches_the_brain_weights(brain):
    """d(drawing MSE)/d(brain weights) through the released body (hand-derived adjoint) equals central
    finite differences of the loss."""
    system = small_system(brain)
    x = images(3)
    labels = torch.tensor([1, 7, 0])
    tg = DigitTargets(dtype=F64)
    steps = int(tg.steps[labels].max())

    def loss() -> torch.Tensor:
        return tg.errors(system.draw(x, steps), labels).mean()

    first = system.brain.weight if brain == "lil" else system.brain.layers[0].weight
    for param in (first, system.body.k):
        err, norm = fd_relative_error(loss, param, coordinates=4, directions=2)
        assert norm > 1e-8 and err < 1e-5, (err, norm)


def test_label_map_cells_equal_independent_single_simulations():
    """Each cell of a tiny label map equals its own release, simulated step by step with MSDN.step and
    labelled by a numpy nearest-target search."""
    system = small_system("mlp", nodes=37, seed=3)
    base = system.displacement(images(10)).detach()
    out = label_maps(system, base, half_width=0.6, grid=3, masses=[0, 13], chunk=7)
    assert out["labels"].shape == (10, 2, 3, 3) and out["deltas"].tolist() == pytest.approx([-0.6, 0.0, 0.6])
    targets = load_targets()
    body = system.body
    cmp = system.cmp
    for d, p, iy, ix in [(0, 0, 0, 2), (4, 1, 1, 1), (9, 1, 2, 0), (7, 0, 2, 2)]:
        disp = base[d: d + 1].clone()
        disp[0, out["masses"][p]] += torch.tensor([out["deltas"][ix], out["deltas"][iy]], dtype=F64)
        state = body.initial_state(1, displacement=disp)
        path = [state.r[0, cmp].clone()]
        with torch.no_grad():
            for _ in range(max(len(t) for t in targets) - 1):
                state = body.step(state)
                path.append(state.r[0, cmp].clone())
        drawing = torch.stack(path).numpy()
        errs = [np.mean((drawing[: len(t)] - t) ** 2) for t in targets]
        assert out["labels"][d, p, iy, ix] == int(np.argmin(errs)), (d, p, iy, ix)
    size = (out["labels"] == np.arange(10)[:, None, None, None]).mean(axis=(2, 3))
    np.testing.assert_allclose(out["size"], size)


def test_masses_joined_to_the_cmp():
    # multiple-circle 37: rings of 20 (fixed), 12 and 4 masses; only the 4 of the innermost ring hold a spring
    # to the CMP
    joined = joined_to_cmp(small_system(nodes=37))
    assert joined.sum() == 4 and joined[-4 - 1: -1].all()  # rows: 12 of ring 1, 4 of ring 2, the CMP


def test_system_round_trip(tmp_path):
    system = small_system("lil")
    with torch.no_grad():
        system.body.k.mul_(1.5)
    save_system(system, tmp_path / "s.pt", {"scale": "smoke"})
    again, extra = load_system(tmp_path / "s.pt")
    assert extra == {"scale": "smoke"} and again.spec == system.spec
    x = images(2)
    torch.testing.assert_close(again.draw(x, 10), system.draw(x, 10))


def test_readout_states_are_positions_every_tenth_of_a_second():
    model = ReadoutSystem(ReadoutSpec(shape="double_circle", nodes=33), seed=0)
    x = images(2).float()
    feats = model.states(x, adjoint=False)
    assert feats.shape == (2, 20 * 17) and model.n_features == 20 * 17  # 20 N_mov numbers (N_mov = 17)
    sys_ = model.system
    r = sys_.release(sys_.displacement(x), 100, adjoint=False, states=True)
    torch.testing.assert_close(feats.view(2, 10, 17, 2)[:, 0], r[:, 10])  # first snapshot at t = 0.1 s
    torch.testing.assert_close(feats.view(2, 10, 17, 2)[:, -1], r[:, 100])  # last at t = 1 s
    brain_only = ReadoutSystem(ReadoutSpec(shape=None, hidden=32), seed=0)
    assert brain_only.n_features == 32 and brain_only(x).shape == (2, 10)


@pytest.mark.parametrize("kind", ["drawing", "readout"])
def test_a_batch_of_images_is_one_simulation_equal_to_one_image_at_a_time(kind):
    """Training batches are one batched simulation of B bodies: the batch-mean loss and its gradients (brain
    weights, k, d, l) equal the mean over B single-image simulations (float64)."""
    if kind == "drawing":
        model = ImageToBody(SystemSpec(brain="mlp", nodes=37, dtype="float64"), 0)
        tg = DigitTargets(dtype=F64)

        def loss_of(x, labels):
            return tg.errors(model.draw(x, int(tg.steps.max())), labels).mean()
        body = model.body
    else:
        model = ReadoutSystem(ReadoutSpec(shape="multiple_circle", nodes=37), 0).double()

        def loss_of(x, labels):
            return torch.nn.functional.cross_entropy(model(x), labels)
        body = model.system.body
    params = [p for p in model.parameters() if p.requires_grad]
    assert any(p is body.k for p in params) and any(p is body.l for p in params)
    x, labels = images(3), torch.tensor([4, 0, 8])

    def grads(loss):
        return [g.clone() for g in torch.autograd.grad(loss, params)]

    loss = loss_of(x, labels)
    losses = [loss_of(x[i: i + 1], labels[i: i + 1]) for i in range(3)]
    assert loss.item() == pytest.approx(sum(one.item() for one in losses) / 3, rel=1e-12)
    batched = grads(loss)
    single = [grads(one) for one in losses]
    for j, g in enumerate(batched):
        torch.testing.assert_close(g, sum(s[j] for s in single) / 3, rtol=1e-12, atol=1e-15)
