"""The readout training's epoch checkpoints: a training interrupted after an epoch and started again from its
checkpoint ends bit for bit where an uninterrupted one ends; a checkpoint of another training, or a damaged one,
is refused with one line and left as it was."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from bptsb_ros.tasks.readout import ReadoutSpec, ReadoutSystem, train_readout


def _images(n: int = 6) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(5)
    x = (rng.uniform(0, 1, (n, 784)) * (rng.uniform(0, 1, (n, 784)) > 0.8)).astype(np.float32)
    return x, np.array([3, 1, 4, 1, 5, 9][:n])


def _model(shape: str | None = "double_circle") -> ReadoutSystem:
    return ReadoutSystem(ReadoutSpec(shape=shape, nodes=9, hidden=8, transient_s=0.3), seed=2)


class Interrupted(Exception):
    pass


def _stop_at(line_start: str):
    """A training ``log`` that interrupts the training when it announces ``line_start`` (an epoch's end is
    announced before that epoch's checkpoint is written, so the previous epoch's is the last on disk)."""
    def log(line: str) -> None:
        if line.startswith(line_start):
            raise Interrupted(line)
    return log


# (shape, spike rule, updates the guard undoes after the interruption at update 6): a strict rule rejects some
# updates and divides the rates on these images, so the guard's state must resume too; without one every update
# is accepted, so the optimiser's state must
CASES = [("double_circle", {"reject_factor": 1.02, "reject_window": 3}, [7, 8, 9, 11]),
         ("double_circle", {"reject_factor": 0.0}, []), (None, {"reject_factor": 0.0}, [])]


@pytest.mark.parametrize(("shape", "rule", "undone"), CASES)
def test_a_training_resumed_from_its_epoch_checkpoint_ends_bit_for_bit_where_an_uninterrupted_one_ends(tmp_path,
                                                                                                        shape, rule,
                                                                                                        undone):
    torch.set_num_threads(1)
    x, y = _images()
    kw = dict(epochs=4, batch=2, seed=3, test=(x, y), **rule)
    whole = _model(shape)
    ref = train_readout(whole, x, y, **kw)
    assert [e["update"] for e in ref.guard["events"] if e["update"] >= 6] == undone

    ckpt = tmp_path / "t" / "ckpt.pt"
    with pytest.raises(Interrupted):
        train_readout(_model(shape), x, y, checkpoint=ckpt, log=_stop_at("double_circle-9: epoch 3/4"
                                                                         if shape else "only brain: epoch 3/4"),
                      **kw)
    first = torch.load(ckpt, weights_only=True)
    assert first["epochs_done"] == 2 and first["spent_s"] > 0
    lines: list[str] = []
    resumed_model = _model(shape)
    resumed = train_readout(resumed_model, x, y, checkpoint=ckpt, log=lines.append, **kw)
    assert lines[0].endswith(f"continuing after epoch 2/4 from {ckpt}")
    assert resumed.losses == ref.losses and len(ref.losses) == 4 * 3
    assert resumed.epoch_accuracy == ref.epoch_accuracy and len(ref.epoch_accuracy) == 4
    assert resumed.guard == ref.guard
    for (name, a), (_, b) in zip(whole.state_dict().items(), resumed_model.state_dict().items()):
        assert torch.equal(a, b), name
    assert resumed.wall_s > first["spent_s"]  # the time of both attempts

    # a finished checkpoint: nothing is trained again, the log is the finished training's
    again_model = _model(shape)
    again = train_readout(again_model, x, y, checkpoint=ckpt, **kw)
    assert again.losses == ref.losses and again.epoch_accuracy == ref.epoch_accuracy
    assert all(torch.equal(a, b) for a, b in zip(whole.state_dict().values(), again_model.state_dict().values()))


def _equal(a, b, where: str = "") -> None:
    """Two saved states are equal entry by entry, tensors bit for bit (the time spent aside)."""
    if isinstance(a, torch.Tensor):
        assert isinstance(b, torch.Tensor) and a.dtype == b.dtype and torch.equal(a, b), where
    elif isinstance(a, dict):
        assert isinstance(b, dict) and set(a) == set(b), where
        for key in a:
            if key != "spent_s":
                _equal(a[key], b[key], f"{where}.{key}")
    elif isinstance(a, (list, tuple)):
        assert type(a) is type(b) and len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b)):
            _equal(x, y, f"{where}[{i}]")
    else:
        assert a == b and type(a) is type(b), where


@pytest.mark.parametrize(("shape", "rule"), [("double_circle", {"reject_factor": 1.0001, "reject_window": 2}),
                                             (None, {"reject_factor": 1.0001, "reject_window": 3})])
def test_the_state_one_epoch_after_a_resume_is_the_uninterrupted_trainings_state_after_that_epoch(tmp_path, shape,
                                                                                                   rule):
    """Every entry of the saved state (parameters, Adam's moments and rates, the guard's history, events,
    counters and saved parameters, the generator) one epoch after resuming from each epoch of a guarded training
    equals the uninterrupted training's after that epoch: nothing the next updates read is lost in between. The
    planted rule rejects updates and divides the rates on these images."""
    torch.set_num_threads(1)
    x, y = _images()
    kw = dict(epochs=4, batch=2, seed=0, test=(x, y), **rule)
    name = "double_circle-9" if shape else "only brain"
    whole = tmp_path / "whole.pt"
    per_epoch: dict[int, bytes] = {}

    def keep(line: str) -> None:  # epoch e's line comes before its save: the file then holds epoch e − 1's state
        if ": epoch " in line and whole.exists():
            per_epoch[int(line.split(": epoch ")[1].split("/")[0]) - 1] = whole.read_bytes()

    ref = train_readout(_model(shape), x, y, checkpoint=whole, log=keep, **kw)
    per_epoch[4] = whole.read_bytes()
    assert ref.guard["divisions"] > 0 and sorted(per_epoch) == [1, 2, 3, 4]
    for cut in (1, 2, 3):
        part = tmp_path / f"from-{cut}.pt"
        part.write_bytes(per_epoch[cut])
        stop = f"{name}: epoch {cut + 2}/4" if cut < 3 else "never"
        try:
            train_readout(_model(shape), x, y, checkpoint=part, log=_stop_at(stop), **kw)
        except Interrupted:
            pass
        after = torch.load(part, weights_only=True)
        assert after["epochs_done"] == cut + 1
        _equal(after, torch.load(tmp_path / "whole.pt", weights_only=True) if cut == 3 else
               _load_bytes(per_epoch[cut + 1], tmp_path / "expected.pt"), f"resumed after epoch {cut}")


def _load_bytes(data: bytes, path):
    path.write_bytes(data)
    return torch.load(path, weights_only=True)


def test_without_a_checkpoint_nothing_is_written_and_the_training_is_the_same(tmp_path):
    x, y = _images()
    kw = dict(epochs=2, batch=3, seed=1, test=(x, y))
    a = train_readout(_model(), x, y, **kw)
    b = train_readout(_model(), x, y, checkpoint=tmp_path / "c.pt", **kw)
    assert a.losses == b.losses and a.epoch_accuracy == b.epoch_accuracy
    assert [p.name for p in tmp_path.iterdir()] == ["c.pt"]


def test_a_checkpoint_of_another_training_is_refused_and_kept(tmp_path):
    x, y = _images()
    ckpt = tmp_path / "c.pt"
    train_readout(_model(), x, y, epochs=1, batch=3, seed=1, checkpoint=ckpt, identity={"data": "set A"})
    before = ckpt.read_bytes()
    for kw, named in (({"seed": 2, "identity": {"data": "set A"}}, "seed 1, not 2"),
                      ({"seed": 1, "identity": {"data": "set B"}}, "data 'set A', not 'set B'"),
                      ({"seed": 1, "identity": {"data": "set A"}, "batch": 2}, "batch 3, not 2"),
                      ({"seed": 1, "identity": {"data": torch.tensor([1, 2])}},
                       "data 'set A', not tensor\\(\\[1, 2\\]\\)")):
        args = {"epochs": 1, "batch": 3, **kw}
        with pytest.raises(ValueError, match=f"{ckpt} holds another training \\({named}\\)"):
            train_readout(_model(), x, y, checkpoint=ckpt, **args)
        assert ckpt.read_bytes() == before
    # the same identity continues (nothing left to train)
    assert len(train_readout(_model(), x, y, epochs=1, batch=3, seed=1, checkpoint=ckpt,
                             identity={"data": "set A"}).losses) == 2


@pytest.mark.parametrize("content", [b"not a checkpoint", None])
def test_a_damaged_or_foreign_checkpoint_is_one_line_and_left_alone(tmp_path, content):
    x, y = _images()
    ckpt = tmp_path / "c.pt"
    if content is None:  # a valid torch file of another kind
        torch.save({"format": 99}, ckpt)
        match = "not a readout checkpoint of format 1"
    else:
        ckpt.write_bytes(content)
        match = "not a readable readout checkpoint"
    before = ckpt.read_bytes()
    with pytest.raises(ValueError, match=match) as err:
        train_readout(_model(), x, y, epochs=1, batch=3, checkpoint=ckpt)
    assert "\n" not in str(err.value) and str(ckpt) in str(err.value)
    assert ckpt.read_bytes() == before


def test_the_time_of_a_resumed_training_counts_every_attempt(tmp_path):
    x, y = _images()
    ckpt = tmp_path / "c.pt"
    kw = dict(epochs=2, batch=3, seed=1, checkpoint=ckpt)
    with pytest.raises(Interrupted):
        train_readout(_model(None), x, y, test=(x, y), log=_stop_at("only brain: epoch 2/2"), **kw)
    state = torch.load(ckpt, weights_only=True)
    state["spent_s"] = 1000.0  # planted: the first attempt's time
    torch.save(state, ckpt)
    log = train_readout(_model(None), x, y, test=(x, y), **kw)
    assert 1000.0 < log.wall_s < 1000.0 + 60.0


def _set(path: tuple, value):
    def edit(state: dict) -> None:
        node = state
        for key in path[:-1]:
            node = node[key]
        node[path[-1]] = value(node[path[-1]]) if callable(value) else value
    return edit


def _drop(key: str):
    return lambda state: state.pop(key)


#: a sound rejection event (as UpdateGuard writes one)
EVENT = {"update": 1, "loss": 2.5, "reason": "loss spike", "reference": 1.0, "count": 1, "divided": False,
         "rates": {"0": 0.01}}
# (an edit of a sound checkpoint after epoch 1 of 2, the entry the one-line refusal names)
TAMPERED = [
    (_set(("epochs_done",), 5), "epochs_done is 5, outside 0 … 2"),
    (_set(("updates",), 1), "updates is 1, outside 2 … 2"),
    (_set(("spent_s",), -1.0), "spent_s is -1.0, not a time ≥ 0"),
    (_drop("guard"), "lacks 'guard'"),
    (_set(("model", "readout.weight"), lambda w: w * float("nan")),
     "model.readout.weight holds a value that is not finite"),
    (_set(("model", "readout.weight"), lambda w: w[:, :-1]), "model.readout.weight has shape"),
    (_set(("model", "system.body.k"), lambda k: -k), "model.system.body.k has a negative value"),
    (_set(("model", "system.body.mass"), lambda m: 2 * m), "model.system.body.mass differs from the one"),
    (_set(("optimizer", "param_groups", 0, "lr"), lambda r: 100 * r), "above the config's"),
    (_set(("optimizer", "state", 0, "exp_avg_sq"), lambda v: -v - 1), "exp_avg_sq has a negative value"),
    (_set(("guard", "history"), lambda h: h[:-1]), "guard.history holds 1 losses, not one per update (2)"),
    (_set(("epoch_accuracy",), [1.5]), "epoch_accuracy is not 1 accuracies in [0, 1]"),
    (_set(("batch_order", "bit_generator"), "MT19937"), "batch_order is not the state of a PCG64 generator"),
    (_set(("batch_order", "state"), "x"), "batch_order.state is not a PCG64 state"),
    (_set(("batch_order", "has_uint32"), 10**400), "batch_order.has_uint32 is 1000000"),
    (_set(("epochs_done",), 10**400), "epochs_done is 1000000"),
    (_set(("spent_s",), 10**400), "spent_s is 1000000"),
    (_set(("format",), torch.tensor([1, 1])), "not a readout checkpoint of format 1"),
    (_set(("optimizer", "param_groups", 0), lambda g: {k: v for k, v in g.items() if k != "betas"}), "lacks 'betas'"),
    (_set(("optimizer", "state", 0), lambda st: {"step": st["step"]}), "holds ['step'], not Adam's"),
    (_set(("guard", "events"), [{}]), "guard.events[0] lacks"),
    (_set(("guard", "events"), [{**EVENT, "loss": float("nan")}]), "guard.events[0].loss is nan, not a finite"),
    (_set(("guard", "events"), [{**EVENT, "update": 7}]), "guard.events[0].update is 7, outside 0 … 1"),
    (_set(("guard", "events"), [{**EVENT, "rates": {"0": -1.0}}]), "guard.events[0].rates is not a mapping of"),
    (_set(("guard", "saved", "params", 4), lambda k: -k - 1), "guard.saved.params[4] (the body's k) has a negative"),
]


@pytest.mark.parametrize(("edit", "named"), TAMPERED)
def test_a_tampered_checkpoint_is_refused_in_one_line_naming_the_entry_and_kept(tmp_path, edit, named):
    x, y = _images(4)
    ckpt = tmp_path / "c.pt"
    kw = dict(epochs=2, batch=2, seed=1, test=(x, y), checkpoint=ckpt)
    with pytest.raises(Interrupted):
        train_readout(_model(), x, y, log=_stop_at("double_circle-9: epoch 2/2"), **kw)
    sound = torch.load(ckpt, weights_only=True)
    state = torch.load(ckpt, weights_only=True)
    edit(state)
    torch.save(state, ckpt)
    before = ckpt.read_bytes()
    with pytest.raises(ValueError) as err:
        train_readout(_model(), x, y, **kw)
    message = str(err.value)
    assert named in message and message.startswith(f"{ckpt}: ") and "\n" not in message
    assert ckpt.read_bytes() == before
    torch.save(sound, ckpt)  # the sound state resumes to the end
    assert len(train_readout(_model(), x, y, **kw).epoch_accuracy) == 2
