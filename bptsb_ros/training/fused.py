"""The fused training path (``training.backend: fused``): an SWG training window — SWG rest lengths, body,
loss and the gradient of every trained parameter — as one numba call, and the SGD update of every parameter
group, with the projection of k, d, l onto [0, ∞), as another (:mod:`bptsb_ros.training.fused_kernel`).

No autograd: the parameters are only the body's (k, d, l) and the SWG's (A, φ), updated in place through numpy
views of the same tensors the optimiser holds, so the :class:`~bptsb_ros.training.guard.UpdateGuard` saves,
restores and divides the rates exactly as on the other paths (the rates are read from the optimiser's groups at
every update). The equations and their order are the numba path's; results agree with it to rounding
(tests/training/test_fused.py: gradients to 1e-12 in float64, parameters after many updates to 1e-10).

What it covers: the Lissajous single-curve task (``LissajousTask``: CMP position loss) and locomotion
(``LocomotionTask``: the speed-block loss, its ramp or constant target, velocity after or before each step's
update, the periodic headwind, the warm-up), with SGD (no momentum, weight decay, dampening or Nesterov) and the
hand-derived adjoint, on CPU. The feedback layer of an SWG agent is fitted after training, outside every training
window, so it does not stand in the way. Lissajous switching (``tasks.switching.train_switching``, its
own loop) uses :class:`GivenTargetLoss`: its wind-dependent target and wind forces are written in before each
window. The NARMA and memory tasks fuse their own episodes (``NarmaTask.fused_episodes``: the brain's forces once
per input block, the body as one autograd node, :mod:`bptsb_ros.body.held_window`) and keep the optimiser's own
update, Adam included. Anything else — MNIST, Adam on the SWG tasks, ``training.adjoint: false`` — trains on the
numba path, and the trainer says so in one line (:func:`fused_unsupported`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from bptsb_ros.body import compile_notice
from bptsb_ros.body.clock import steps_per_period
from bptsb_ros.body.msdn import _NUMPY, MSDN, BodyState, SimulationDiverged
from bptsb_ros.brains import SineWaveGenerator
from bptsb_ros.training import fused_kernel
from bptsb_ros.training.fused_kernel import OUT_GRADS_OK, OUT_LOSS, OUT_STATE_OK, PARAMETERS

#: SGD options the fused update implements (their torch defaults); any other value falls back
_SGD_DEFAULTS = {"momentum": 0, "dampening": 0, "weight_decay": 0, "nesterov": False, "maximize": False}


def fused_unsupported(task, optimizer: torch.optim.Optimizer, *, adjoint: bool = True) -> str | None:
    """Why the fused path cannot train ``task`` with ``optimizer`` (one phrase), or None when it can."""
    from bptsb_ros.body.held_window import held_window_unsupported

    kind = getattr(task, "fused_window", None)  # the task's capability (``Task.fused_window``), not its class
    if kind == "episodes":  # its episodes are fused by the task itself (``fused_episodes``) where they can be
        return held_window_unsupported(task.agent.body, adjoint=adjoint) or "the NARMA task fuses its own episodes"
    if kind not in ("lissajous", "locomotion"):
        return (f"it covers the Lissajous single-curve, locomotion and NARMA / memory tasks, not "
                f"{getattr(task, 'name', type(task).__name__)!r}")
    if not adjoint:
        return "training.adjoint is false (plain autograd was asked for)"
    return _optimizer_unsupported(optimizer) or _body_unsupported(task.agent.body, task.agent.brain)


def _optimizer_unsupported(optimizer: torch.optim.Optimizer) -> str | None:
    if type(optimizer) is not torch.optim.SGD:
        return f"it implements plain SGD, the optimiser is {type(optimizer).__name__}"
    for group in optimizer.param_groups:
        for key, default in _SGD_DEFAULTS.items():
            if group.get(key, default) != default:
                return f"it implements plain SGD, the optimiser has {key} = {group[key]}"
    return None


def _body_unsupported(body: MSDN, brain) -> str | None:
    if not isinstance(brain, SineWaveGenerator):
        return f"it needs an SWG brain, not {type(brain).__name__}"
    if body.k.device.type != "cpu":
        return "it runs on CPU"
    if body.k.dtype not in _NUMPY:
        return f"it runs in float32 or float64, not {body.k.dtype}"
    return None


@dataclass(frozen=True)
class LissajousLoss:
    """``LissajousTask``'s loss: mean over the window's steps and x, y of (CMP − target)², target x = X cos(αω t),
    y = Y sin(βω t + δ) [m; ω rad/s]; ``cmp``: the CMP's row among the movable masses."""

    x_amp: float
    y_amp: float
    alpha: float
    beta: float
    delta: float
    omega: float
    cmp: int


@dataclass(frozen=True)
class LocomotionLoss:
    """``LocomotionTask``'s loss: mean over blocks of ``block`` steps of (block-mean of the mean x-velocity −
    target)²; target = ``target_speed`` [m/s] when given, else ``slope`` × (block end − training's first step)·Δt;
    ``before``: each step's velocity before its update (the published code); ``wind_force`` [N] along x on every
    mass while the wind blows (``wind_period`` [s]: calm for its first half; 0: always)."""

    block: int
    slope: float
    target_speed: float | None
    before: bool
    wind_force: float
    wind_period: float


@dataclass(frozen=True)
class GivenTargetLoss:
    """Lissajous switching's loss: mean over steps and x, y of (CMP − target)², the target (W, 2) [m] and the
    external forces (W, M, 2) [N] written by the caller before every window (:meth:`FusedSwgWindow.set_inputs`)."""

    cmp: int


class FusedSwgWindow:
    """One body (batch 1) and its SWG trained window by window: :meth:`window` measures loss and gradients,
    :meth:`step` applies the SGD update of ``optimizer``'s groups in place.

    Args:
        body: the trained body (its k, d, l are updated in place).
        swg: its SWG (amplitude A and phase φ updated in place).
        optimizer: plain SGD over (some of) those parameters; a parameter in no group is not trained.
        window: W, steps per window.
        loss: the task's loss (:class:`LissajousLoss`, :class:`LocomotionLoss` or :class:`GivenTargetLoss`).
    """

    def __init__(self, body: MSDN, swg: SineWaveGenerator, optimizer: torch.optim.Optimizer, window: int,
                 loss: LissajousLoss | LocomotionLoss | GivenTargetLoss) -> None:
        why = _optimizer_unsupported(optimizer) or _body_unsupported(body, swg)
        if why:
            raise ValueError(f"the fused path cannot train this: {why}")
        if window < 1:
            raise ValueError(f"window must be >= 1 step, got {window}")
        w, m, e = int(window), body.n_movable, body.topology.n_springs
        wind = False
        if isinstance(loss, (LissajousLoss, GivenTargetLoss)):
            if not 0 <= loss.cmp < m:
                raise ValueError("the fused Lissajous window needs a body with a central mass point")
            self.cmp = int(loss.cmp)
            if isinstance(loss, LissajousLoss):
                self.kind = fused_kernel.LISSAJOUS
                self.target = np.array([loss.x_amp, loss.y_amp, loss.alpha * loss.omega, loss.beta * loss.omega,
                                        loss.delta, body.dt], dtype=np.float64)
            else:
                self.kind, wind = fused_kernel.GIVEN_TARGET, True
                self.target = np.zeros(6, dtype=np.float64)
            scales = (1.0 / (2 * w), 0.0, 0.0)
        else:
            if loss.block < 1 or w % loss.block:
                raise ValueError(f"the window ({w} steps) must be a whole number of speed blocks ({loss.block})")
            self.kind, self.cmp, wind = fused_kernel.LOCOMOTION, 0, loss.wind_force != 0
            constant = math.nan if loss.target_speed is None else float(loss.target_speed)
            #: [block, training's first step (set by the caller), slope, Δt, constant, before, wind, wind period]
            self.target = np.array([loss.block, 0.0, loss.slope, body.dt, constant, float(loss.before),
                                    loss.wind_force, loss.wind_period], dtype=np.float64)
            scales = (1.0 / (w // loss.block), float(loss.block), float(m))
        self.body, self.swg, self.optimizer, self.steps = body, swg, optimizer, w
        self.tensors = (body.k, body.d, body.l, swg.amplitude, swg.phase)
        self.dtype = body.k.dtype
        np_dtype = _NUMPY[self.dtype]
        # (group index, parameter index) of every trained parameter: by index, because the guard's restore
        # (``optimizer.load_state_dict``) replaces the group dicts
        self._slots: list[tuple[int, int]] = []
        for g, group in enumerate(optimizer.param_groups):
            for p in group["params"]:
                index = next((i for i, t in enumerate(self.tensors) if t is p), None)
                if index is None:
                    raise ValueError("the fused path trains only the body's k, d, l and the SWG's amplitude and "
                                     "phase; the optimiser holds another parameter")
                self._slots.append((g, index))
        self.active = np.zeros(len(PARAMETERS), dtype=np.bool_)
        for _, index in self._slots:
            self.active[index] = True
        self.lr = np.zeros(len(PARAMETERS), dtype=np_dtype)
        n = steps_per_period(swg.omega, body.dt)
        self.clock = np.array([0.0 if n is None else float(n), 0.0 if n is None else 2 * math.pi / n,
                               swg.omega * body.dt / (2 * math.pi)], dtype=np.float64)
        z = np.zeros
        lissajous = self.kind != fused_kernel.LOCOMOTION  # a CMP position loss: the gradient w.r.t. r
        self.work = {
            "rest": z((w, 1, e), np_dtype), "ext": z((w, 1 if wind else 0, m, 2), np_dtype),
            "r_out": z((w, 1, m, 2), np_dtype), "v_out": z((w, 1, m, 2), np_dtype),
            "a_out": z((w, 1, m, 2), np_dtype), "len_out": z((w, 1, e), np_dtype),
            "g_r": z((w if lissajous else 0, 1, m, 2), np_dtype), "g_v": z((0 if lissajous else w, 1, m, 2), np_dtype),
            "g_none4": z((0, 0, 0, 0), np_dtype), "g_none3": z((0, 0, 0), np_dtype),
            "lam_r": z((1, m, 2), np_dtype), "lam_v": z((1, m, 2), np_dtype), "lam_a": z((1, m, 2), np_dtype),
            "g_kb": z((1, e), np_dtype), "g_db": z((1, e), np_dtype), "g_rest": z((w, 1, e), np_dtype),
            "g_ext": z((w, 1, m, 2) if wind else (0, 0, 0, 0), np_dtype),
            "sin_t": z(w, np_dtype), "cos_t": z(w, np_dtype), "cph": z(e, np_dtype), "sph": z(e, np_dtype),
            "tgt": z((w, 2), np_dtype),
        }
        #: the last window's gradients (5, E), rows in ``PARAMETERS`` order
        self.grads = z((len(PARAMETERS), e), np_dtype)
        self.out = z(3, np.float64)
        self.unit = np.array([0.0, 1.0, 2.0, *scales], dtype=np_dtype)
        _, _, offset, mass, coef = body.kernel_constants(self.dtype)  # copies of buffers that training never changes
        self._fixed = (self.kind, self.clock, self.target, self.cmp, coef.copy(), self.unit,
                       body.integrator == "verlet", bool(body.environment.ground_clamp), body.spring_i, body.spring_j,
                       offset.copy(), mass.copy())
        self._work_args = tuple(self.work[key] for key in (
            "rest", "ext", "r_out", "v_out", "a_out", "len_out", "g_r", "g_v", "g_none4", "g_none3", "lam_r", "lam_v",
            "lam_a", "g_kb", "g_db", "g_rest", "g_ext", "sin_t", "cos_t", "cph", "sph", "tgt"))
        self._views_key: tuple[int, ...] | None = None
        self._views_cache: tuple[np.ndarray, ...] = ()
        self._last: tuple[BodyState | None, tuple[np.ndarray, ...]] = (None, ())

    def _views(self) -> tuple[np.ndarray, ...]:
        """numpy views sharing memory with the parameter tensors (a restore or a checkpoint load copies into them
        in place; taken afresh should a tensor's storage change)."""
        key = tuple(t.data_ptr() for t in self.tensors)
        if key != self._views_key:
            self._views_cache = tuple(t.detach().numpy() for t in self.tensors)
            self._views_key = key
        return self._views_cache

    def _start(self, state: BodyState) -> tuple[np.ndarray, ...]:
        """The start state as C-contiguous numpy arrays (those of the last final state without a copy)."""
        if state is self._last[0]:
            return self._last[1]
        np_dtype = _NUMPY[self.dtype]
        arrays = tuple(np.ascontiguousarray(x.detach().numpy(), dtype=np_dtype) for x in (state.r, state.v, state.a))
        if arrays[0].shape[0] != 1:
            raise ValueError(f"the fused window trains one body, got a state of batch {arrays[0].shape[0]}")
        return arrays

    def window(self, state: BodyState) -> tuple[float, bool, BodyState]:
        """Simulate W steps from ``state`` (B = 1) with the current parameters: (loss, gradients finite, the
        final state). The gradients are in :attr:`grads`. A window that diverged raises SimulationDiverged
        (``MSDN.check_finite``'s message)."""
        loss, grads_ok, final, failure = self.run(state)
        if failure is not None:
            raise SimulationDiverged(failure)
        return loss, grads_ok, final

    def run(self, state: BodyState) -> tuple[float, bool, BodyState, str | None]:
        """:meth:`window` without raising: (loss, gradients finite, final state, None), or for a diverged window
        (its loss, False, its final state, ``MSDN.check_finite``'s message)."""
        body, w = self.body, self.work
        r0, v0, a0 = self._start(state)
        args = (r0, v0, a0, *self._views(), self.swg.driven.numpy(), int(state.step), *self._fixed,
                *self._work_args, self.grads, self.out)
        if not fused_kernel.swg_window.overloads:  # the first window in this process: say so if it compiles
            compile_notice.announce_if_cold(fused_kernel.swg_window, args, fused_kernel.COMPILE_S)
        fused_kernel.swg_window(*args)
        last = tuple(w[key][-1].copy() for key in ("r_out", "v_out", "a_out", "len_out"))
        final = BodyState(*(torch.from_numpy(x) for x in last), state.step + self.steps)
        if not self.out[OUT_STATE_OK]:
            try:
                body.check_finite(final)
            except SimulationDiverged as err:
                return float(self.out[OUT_LOSS]), False, final, str(err)
            raise AssertionError("the fused window flagged a state that MSDN.check_finite accepts")
        self._last = (final, last[:3])
        grads_ok = bool(self.out[OUT_GRADS_OK]) or self.gradients_finite()  # the kernel checks all five
        return float(self.out[OUT_LOSS]), grads_ok, final, None

    def set_inputs(self, target: torch.Tensor, forces: torch.Tensor) -> None:
        """The next window's target (W, 2) [m] and external forces (W, M, 2) or (W, 1, M, 2) [N] (``GivenTargetLoss``),
        cast to the model dtype."""
        if self.kind != fused_kernel.GIVEN_TARGET:
            raise ValueError("set_inputs is for the GivenTargetLoss window")
        w = self.work
        np.copyto(w["tgt"], target.detach().numpy(), casting="same_kind")
        np.copyto(w["ext"], forces.detach().numpy().reshape(w["ext"].shape), casting="same_kind")

    def gradients_finite(self) -> bool:
        """True when the last window's gradients of the optimiser's parameters are finite (as
        ``UpdateGuard.gradients_finite``: a parameter in no group does not count)."""
        return bool(np.isfinite(self.grads[self.active]).all())

    def step(self) -> None:
        """SGD with each group's current rate on the last window's gradients, then k, d, l ← max(·, 0)."""
        groups = self.optimizer.param_groups
        for g, index in self._slots:
            self.lr[index] = groups[g]["lr"]
        fused_kernel.sgd_update(*self._views(), self.grads, self.lr, self.active)

    def gradients(self) -> dict[str, torch.Tensor]:
        """The last window's gradients by parameter name, as tensors (copies)."""
        return {name: torch.from_numpy(self.grads[i].copy()) for i, name in enumerate(PARAMETERS)}


class FusedSwgTraining:
    """The fused path driving a ``LissajousTask`` or ``LocomotionTask``: :meth:`update_loss` runs the task's next
    window (advancing its carried state as ``SwgWindowTask.run_window`` does; locomotion: after its warm-up,
    ``task.prepare``) and returns (loss, gradients finite); :meth:`step` updates."""

    def __init__(self, task, optimizer: torch.optim.Optimizer) -> None:
        agent = task.agent
        loss: LissajousLoss | LocomotionLoss
        if task.fused_window == "lissajous":
            lc, brain, body = agent.config["lissajous"], agent.config["brain"], agent.config["body"]
            amp = float(lc["amplitude_fraction"]) * float(body["size"])  # as tasks.lissajous.target_from_config
            loss = LissajousLoss(amp, amp, float(lc["alpha"]), float(lc["beta"]), float(lc["delta"]),
                                 float(brain["omega"]), agent.body.cmp_local)
        else:
            loc = task.cfg.locomotion
            loss = LocomotionLoss(loc.speed_block, loc.target_slope, loc.target_speed, loc.loss_velocity == "before",
                                  loc.wind_force, loc.wind_period)
        self.task, self.locomotion = task, isinstance(loss, LocomotionLoss)
        self.fused = FusedSwgWindow(agent.body, agent.brain, optimizer, task.window, loss)

    def update_loss(self, index: int) -> tuple[float, bool]:
        del index
        if self.locomotion:
            self.task.prepare()  # the warm-up windows, once (idempotent)
            self.fused.target[1] = float(self.task.train_start_step)
        loss, grads_ok, final = self.fused.window(self.task.state)
        self.task.state = final
        return loss, grads_ok

    def step(self) -> None:
        self.fused.step()


def fused_training(task, optimizer: torch.optim.Optimizer, *, adjoint: bool = True
                   ) -> tuple[FusedSwgTraining | None, str | None]:
    """The fused path for ``task`` (and the reason it is None when the task or optimiser is not covered)."""
    why = fused_unsupported(task, optimizer, adjoint=adjoint)
    return (None, why) if why else (FusedSwgTraining(task, optimizer), None)
