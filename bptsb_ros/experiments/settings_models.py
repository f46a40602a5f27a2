"""What each ``bptsb reproduce`` experiment can be told: one pydantic model per experiment.

Each model declares every setting of one experiment as a typed field with its bounds and help text
(``Field(ge=..., le=..., description=...)``), and each rule across its settings as a model validator. The values
live beside this module, in ``settings/<experiment>.yaml``: each scale (``smoke``, ``short``, ``paper``) is one
instance of the model, and the named variants (``variants``) are instances of its :attr:`variant_model`.
:mod:`~bptsb_ros.experiments.experiment_settings` reads those files and the ``--set`` overrides into these
models. A new experiment adds its model here and names it in :data:`SETTINGS_MODELS`.

All the models are in this one file, not beside each experiment: several experiments share a module
(``lissajous_switching.py`` runs three) or a variant model (:class:`SwitchingVariant`, :class:`AblationVariant`),
the settings of a family are declared once in a base model its experiments extend (:class:`MnistSplitSettings`,
:class:`SwitchingTrainingSettings`, :class:`LocomotionAgentSettings`: the three locomotion experiments share
agents only while their agent settings are alike), and checking a ``--set`` or printing ``--show-config`` needs no
experiment code (nor torch) imported.

The types, exactly as the experiments read them:

- :data:`Int`: an integer (not a bool, not a float such as ``3.0``);
- :data:`Float`: a float; an integer is taken as a float, and so is the text ``1e-05`` (YAML 1.1 reads a number in
  exponent form without a decimal point as a text);
- :data:`Number`: an integer or a float, kept as written (a duration passed on as it is: ``4`` and ``4.0`` give
  different agent keys);
- :data:`Str` and :data:`Bool`: a text, true or false, nothing converted;
- ``tuple[T, ...]``: a list (of the YAML file or of ``--set``) of one of those, each item with its bounds, the
  whole with ``min_length``/``max_length`` where its length is fixed; ``X | None``: null allowed.

Every number has a ``ge`` and an ``le`` (bounds a user would never need to exceed: ``--set sim_time=1e300`` is
refused, not run until killed; a test checks every field of every model), and no number may be inf or nan.

A rule is an ``@model_validator(mode="after")`` that raises :func:`rule_broken` with the rule as text and the
reason it must hold; a rule that reads a nullable setting holds while that setting is null, as one that reads an
item of an empty list does (``stages[0] == 0``): each validator checks for ``None`` (or the empty list) itself
before it compares.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterable
from typing import Annotated, Any, ClassVar, Self

from pydantic import BaseModel, BeforeValidator, ConfigDict, Field, Strict, field_validator, model_validator

from bptsb_ros.files.untrusted_yaml import bounded_repr

#: a number in exponent form without a decimal point (``1e-05``, ``2E+3``), which YAML 1.1 leaves a text
FLOAT_TEXT = re.compile(r"[-+]?[0-9]+(?:\.[0-9]*)?[eE][-+]?[0-9]+")


def _as_float(value: Any) -> Any:
    """An integer or a number text (``1e-05``) as a float; anything else as it is, for the strict float to judge."""
    if isinstance(value, str) and FLOAT_TEXT.fullmatch(value.strip()):
        return float(value)
    if isinstance(value, int) and not isinstance(value, bool):
        try:
            return float(value)
        except OverflowError:  # an integer beyond any float
            raise ValueError("Input should be a finite number") from None
    return value


def _as_number(value: Any) -> Any:
    """An integer or a float kept as it is (a number text read as a float); ValueError for anything else."""
    if isinstance(value, str) and FLOAT_TEXT.fullmatch(value.strip()):
        value = float(value)
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueError("Input should be a valid number")
    if isinstance(value, float) and not math.isfinite(value):
        raise ValueError("Input should be a finite number")
    return value


Int = Annotated[int, Strict()]
"""An integer setting: a bool or a float (even ``3.0``) is refused."""
Float = Annotated[float, BeforeValidator(_as_float), Strict()]
"""A float setting: an integer becomes a float, the text ``1e-05`` too; a bool or another text is refused."""
Number = Annotated[Annotated[int, Strict()] | Annotated[float, Strict()], BeforeValidator(_as_number)]
"""An integer or a float setting, kept as given (``4`` stays an int, ``4.0`` a float)."""
Str = Annotated[str, Strict()]
"""A text setting (a number is refused, not turned into a text)."""
Bool = Annotated[bool, Strict()]
"""A true/false setting (``1`` or ``"yes"`` is refused)."""


class _SettingsModel(BaseModel):
    """Common ground of the settings and the variant models: every setting given, none unknown, frozen, finite."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    @field_validator("*", mode="before")
    @classmethod
    def _a_list_is_a_list(cls, value: Any) -> Any:
        """A list setting takes a list or a tuple, not a set or another iterable (which pydantic would take)."""
        if isinstance(value, (str, bytes, list, tuple)) or not isinstance(value, Iterable):
            return value
        raise ValueError(f"Input should be a list, not a {type(value).__name__}")


class VariantSettings(_SettingsModel):
    """The settings of one named variant (protocol) of an experiment, the same at every scale."""


class ExperimentSettings(_SettingsModel):
    """The settings of one experiment at one scale (``ctx.settings``); a subclass per experiment."""

    #: the model of the experiment's named variants (``variants`` in its settings file), None: it has none
    variant_model: ClassVar[type[VariantSettings] | None] = None


def rule_broken(settings: BaseModel, check: str, why: str) -> ValueError:
    """The error a rule raises when it does not hold: ``check`` (the rule as text), the values of the settings it
    names, and ``why`` it must hold."""
    names = sorted(set(re.findall(r"[a-z_][a-z0-9_]*", check)) & set(type(settings).model_fields))
    given = ", ".join(f"{name} = {shown(getattr(settings, name))}" for name in names)
    return ValueError(f"{check} does not hold ({given}): {why}")


def shown(value: Any) -> str:
    """``value`` for a message: a short printable text as it is, anything else bounded and escaped."""
    text = str(value)
    return text if isinstance(value, str) and text.isprintable() and len(text) <= 80 else bounded_repr(value)


# -- MNIST (Fig. 2 and the MNIST supplement) -----------------------------------------------------------------------

def odd_grid(settings: Any) -> Any:
    """The rule of a label map's ``grid``: odd, so that it has a cell at Δ = 0."""
    if not settings.grid % 2 == 1:
        raise rule_broken(settings, "grid % 2 == 1", "the label map has a cell at Δ = 0 (an odd grid)")
    return settings


class MnistSplitSettings(ExperimentSettings):
    """The images of an MNIST experiment that trains on a split (its own settings follow these)."""

    n_train: Annotated[Int, Field(ge=1, le=1_000_000)] | None = Field(
        description="training images (null: every image of the split)")
    n_test: Annotated[Int, Field(ge=1, le=1_000_000)] | None = Field(
        description="test images (null: every image of the split)")


class MnistDrawingSettings(MnistSplitSettings):
    """What ``mnist-drawing`` reads from ``ctx.settings``."""

    epochs: Int = Field(ge=1, le=1_000_000, description="training epochs of each of the four systems (batch 50)")


class MnistPcaSettings(MnistSplitSettings):
    """What ``mnist-pca`` reads from ``ctx.settings``."""

    epochs: Int = Field(ge=1, le=1_000_000, description="training epochs of the system (batch 50)")


class MnistLabelmapSettings(MnistSplitSettings):
    """What ``mnist-labelmap`` reads from ``ctx.settings``."""

    epochs: Int = Field(ge=1, le=1_000_000, description="training epochs of the system (batch 50)")
    grid: Int = Field(
        ge=2, le=1001,
        description="label-map cells per axis (paper scale ours: neither the paper nor the configs give the "
        "resolution)")

    @model_validator(mode="after")
    def _odd_grid(self) -> Self:
        return odd_grid(self)


class MnistSpecific100Settings(ExperimentSettings):
    """What ``mnist-specific100`` reads from ``ctx.settings``."""

    per_digit: Int = Field(ge=1, le=10_000, description="training images per digit (the paper: 10, 100 images in all)")
    epochs: Int = Field(
        ge=1, le=1_000_000,
        description="training epochs (paper scale ours: the paper and the configs give none; 2 updates per epoch on "
        "100 images)")
    grid: Int = Field(ge=2, le=1001, description="label-map cells per axis (paper scale ours, as mnist-labelmap)")

    @model_validator(mode="after")
    def _odd_grid(self) -> Self:
        return odd_grid(self)


class MnistReadoutSettings(MnistSplitSettings):
    """What ``mnist-readout`` reads from ``ctx.settings``."""

    epochs: Int = Field(
        ge=1, le=1_000_000,
        description="training epochs (the supplement: \"These systems were optimized for 100 epochs\")")
    guard_factor: Number = Field(
        ge=0, le=1000,
        description="the update guard undoes a batch loss above this × its reference; 0 (default): non-finite steps "
        "only — neither the paper nor the published-code facts give MNIST a spike rule, and the time-"
        "series rule (10) froze both N_mov 65 readouts on ordinary minibatch spikes")
    guard_window: Int = Field(
        ge=1, le=10_000_000,
        description="the guard's reference: the mean of this many last batch losses (one epoch: 1200 at batch 50)")


# -- time series and IPC (Fig. 3 and the time-series supplement) ---------------------------------------------------

class AblationVariant(VariantSettings):
    """An ablation of ``narma-emulation`` and ``narma-ipc``: a choice the paper leaves open, made otherwise."""

    help: Str = Field(description="what the variant changes, in words (prefixes its rows and claims)")
    brains: tuple[Str, ...] = Field(description="the brains (lil, mlp) whose systems this variant trains")
    variant_overrides: tuple[Str, ...] = Field(description="--set overrides of the training config in this variant")


class NarmaEmulationSettings(ExperimentSettings):
    """What ``narma-emulation`` reads from ``ctx.settings``."""

    variant_model: ClassVar[type[VariantSettings] | None] = AblationVariant

    epochs: Int = Field(ge=1, le=1_000_000, description="training epochs of each system")
    eval_inputs: Int = Field(ge=2, le=1_000_000, description="held-out inputs u the trained systems are evaluated on")
    washout: Int = Field(ge=0, le=100_000, description="first held-out inputs left out of the NMSE")
    config: Str = Field(description="the packaged training config (config/NAME.yaml)")
    config_overrides: tuple[Str, ...] = Field(description="--set overrides of that config (key=value)")
    ablations: Bool = Field(
        description="also train the ablation variants (after the first): each retrains the systems it names with its"
        " overrides and is judged against the first variant's other systems")

    @model_validator(mode="after")
    def _washout_within_eval(self) -> Self:
        if not self.washout < self.eval_inputs:
            raise rule_broken(self, "washout < eval_inputs",
                              "the NMSE is taken over the held-out inputs after the washout")
        return self


class NarmaIpcSettings(ExperimentSettings):
    """What ``narma-ipc`` reads from ``ctx.settings``."""

    variant_model: ClassVar[type[VariantSettings] | None] = AblationVariant

    stages: tuple[Annotated[Int, Field(ge=0, le=1_000_000)], ...] = Field(
        description="epoch counts after which the IPC is measured: 0 (untrained), then growing; the last is the "
        "training's length")
    eval_inputs: Int = Field(ge=2, le=1_000_000, description="held-out inputs u the IPC is computed from")
    max_delay: Int = Field(ge=1, le=200, description="longest input delay of the IPC basis [inputs]")
    washout: Int = Field(ge=0, le=100_000, description="first held-out inputs left out")
    config: Str = Field(description="the packaged training config (config/NAME.yaml)")
    config_overrides: tuple[Str, ...] = Field(description="--set overrides of that config (key=value)")
    ablations: Bool = Field(
        description="also train the ablation variants (after the first): each retrains the systems it names with its"
        " overrides and is judged against the first variant's other systems")

    @model_validator(mode="after")
    def _washout_and_delays_within_eval(self) -> Self:
        if not self.washout + self.max_delay < self.eval_inputs:
            raise rule_broken(self, "washout + max_delay < eval_inputs",
                              "the IPC reads the held-out inputs after the washout, at delays up to max_delay")
        return self

    @model_validator(mode="after")
    def _starts_untrained(self) -> Self:
        if self.stages and not self.stages[0] == 0:  # an empty list has no first stage: the rule holds
            raise rule_broken(self, "stages[0] == 0", "the first stage is the untrained system")
        return self


class MemoryTaskSettings(ExperimentSettings):
    """What ``memory-task`` reads from ``ctx.settings``."""

    epochs: Int = Field(ge=1, le=1_000_000, description="training epochs of each system")
    delays: tuple[Annotated[Int, Field(ge=1, le=1000)], ...] = Field(
        description="the delays Δt trained [inputs] (the paper: 1…17)")
    n_seeds: Int = Field(ge=1, le=1000, description="seeds per body and delay (seeds 1000·SEED, 1000·SEED + 1, …)")
    eval_inputs: Int = Field(ge=2, le=1_000_000, description="held-out inputs u the systems are evaluated on")
    max_delay: Int = Field(ge=1, le=200, description="longest input delay of the IPC basis [inputs]")
    washout: Int = Field(ge=0, le=100_000, description="first held-out inputs left out")
    config: Str = Field(description="the packaged training config (config/NAME.yaml)")
    config_overrides: tuple[Str, ...] = Field(description="--set overrides of that config (key=value)")
    gangs: Bool = Field(
        description="the trainings of each worker as one gang: their episodes one batched simulation (same numbers)")
    ipc_stages: tuple[Annotated[Int, Field(ge=0, le=1_000_000)], ...] = Field(
        description="epoch counts at which the first seed's Δt = 8 outputs' IPC is also measured (0: untrained; "
        "those below epochs count, the trained system always does)")
    population: Bool = Field(
        description="each body's trainings as populations (stacked parameters: one brain, kernel, backward and "
        "optimiser step for all; each member's numbers its solo training's to rounding); replaces gangs")

    @model_validator(mode="after")
    def _washout_and_delays_within_eval(self) -> Self:
        if not self.washout + self.max_delay < self.eval_inputs:
            raise rule_broken(self, "washout + max_delay < eval_inputs",
                              "the NMSE and the IPC read the held-out inputs after the washout, at delays up to "
                              "max_delay")
        return self

    @model_validator(mode="after")
    def _two_delays_or_more(self) -> Self:
        if not len(self.delays) >= 2:
            raise rule_broken(self, "len(delays) >= 2", "the claims compare the NMSE across delays")
        return self

    @model_validator(mode="after")
    def _jobs_bounded(self) -> Self:
        if not len(self.delays) * self.n_seeds <= 20_000:
            raise rule_broken(self, "len(delays) * n_seeds <= 20000",
                              "two bodies × delays × seeds trainings: at most 40,000 sweep jobs")
        return self


class TargetIpcSettings(ExperimentSettings):
    """What ``target-ipc`` reads from ``ctx.settings``."""

    samples: Int = Field(
        ge=200, le=1_000_000,
        description="inputs u the targets' IPC is computed from (delay 20 and washout 100 taken off)")


class MsdnNonlinearitySettings(ExperimentSettings):
    """What ``msdn-nonlinearity`` reads from ``ctx.settings``."""

    blocks: Int = Field(
        ge=200, le=1_000_000,
        description="input blocks (each held τ = 20 steps) the IPC is computed from")
    max_delay: Int = Field(ge=1, le=200, description="longest input delay of the IPC basis [blocks]")

    @model_validator(mode="after")
    def _delays_within_blocks(self) -> Self:
        if not self.max_delay < self.blocks:
            raise rule_broken(self, "max_delay < blocks", "the IPC basis reaches max_delay blocks back")
        return self


# -- Lissajous and SWG (Fig. 4 and the SWG supplement) -------------------------------------------------------------

class LissajousClosedLoopSettings(ExperimentSettings):
    """What ``lissajous-closed-loop`` reads from ``ctx.settings``."""

    sim_time: Number = Field(ge=0, le=100_000, description="training [s] of simulated time")
    fit_time: Number = Field(ge=0, le=10_000, description="open-loop run the FL is fitted on [s]")
    eval_periods: Int = Field(ge=1, le=10_000, description="periods the loops' errors are measured over")


class LissajousPerturbationVariant(VariantSettings):
    """A named variant (protocol) of ``lissajous-perturbation``."""

    restart: Bool = Field(
        description="restart every trial from the layout + the displacement, at rest, clock at t = 0 (false: kick "
        "the running cycle)")
    eval_windows: Int = Field(
        ge=0, le=100_000,
        description="restart trial: last training windows whose mean error is compared (0 with the kick, whose "
        "eval_periods apply)")


class LissajousPerturbationSettings(ExperimentSettings):
    """What ``lissajous-perturbation`` reads from ``ctx.settings``."""

    variant_model: ClassVar[type[VariantSettings] | None] = LissajousPerturbationVariant

    sim_time: Number = Field(ge=0, le=100_000, description="training [s] of the single-curve agent")
    fit_time: Number = Field(ge=0, le=10_000, description="open-loop run the FL is fitted on [s]")
    n_seeds: Int = Field(ge=1, le=10_000, description="random perturbation patterns per σ (the paper: 100)")
    run_periods: Int = Field(ge=1, le=100_000, description="periods the system runs on after the perturbation")
    eval_periods: Int = Field(ge=1, le=10_000, description="last periods the error is measured over")
    settle_periods: Int = Field(ge=0, le=10_000, description="periods the closed loop runs before the perturbation")

    @model_validator(mode="after")
    def _eval_within_run(self) -> Self:
        if not self.eval_periods <= self.run_periods:
            raise rule_broken(self, "eval_periods <= run_periods",
                              "the error is measured over the last eval_periods of the run_periods run")
        return self


class SwitchingVariant(VariantSettings):
    """A named variant of the switching experiments (``lissajous-switching``, ``lissajous-bifurcation``,
    ``lissajous-timing``): the paper's text, or the published code's wind or protocol."""

    label: Str = Field(description="the variant's name in rows, claims and figures")
    published_wind: Bool = Field(
        description="wind (15·F_wind, +1) N as the published code (false: the paper's (F_wind, 0))")
    curve_on: tuple[Annotated[Float, Field(ge=0, le=100)], ...] = Field(
        min_length=3, max_length=3,
        description="second curve (α, β, δ/π) drawn with wind")
    hold: (Annotated[tuple[Annotated[Int, Field(ge=1, le=10_000)], ...], Field(min_length=2, max_length=2)]
           | None) = Field(
        description="SWG periods (100-step windows) per calm or windy segment, min and max (null: the scale's hold)")
    shift_of_size: Annotated[Number, Field(ge=0, le=10)] | None = Field(
        description="x displacement of the windy target / body size (null: the CMP's own mean wind shift)")
    lr: tuple[Annotated[Float, Field(ge=0, le=1_000_000)], ...] = Field(
        min_length=5, max_length=5,
        description="switching learning rates k, d, l, A, φ")
    lr_decay: Bool = Field(description="every rate ÷10 at 80 % and 90 % of the windows when there are more than 1,000")
    integrator: Str = Field(
        description="body.integrator of the preliminary and the switching training (verlet, published)")


class SwitchingTrainingSettings(ExperimentSettings):
    """How a wind-switching experiment trains its agents (the preliminary single-curve training, then the switching
    training with the wind held for a random number of periods), first in each; its variants are
    :class:`SwitchingVariant`."""

    variant_model: ClassVar[type[VariantSettings] | None] = SwitchingVariant

    pretrain_time: Number = Field(ge=0, le=100_000, description="preliminary single-curve training [s]")
    switching_time: Number = Field(ge=0, le=300_000,
                                   description="switching training [s] of each agent (the paper: 30,000 s)")
    hold: tuple[Annotated[Int, Field(ge=1, le=10_000)], ...] = Field(
        min_length=2, max_length=2,
        description="the wind holds each state this many periods, min and max")

    @model_validator(mode="after")
    def _hold_ordered(self) -> Self:
        if not self.hold[0] <= self.hold[1]:
            raise rule_broken(self, "hold[0] <= hold[1]", "the shortest hold comes first")
        return self


class LissajousSwitchingSettings(SwitchingTrainingSettings):
    """What ``lissajous-switching`` reads from ``ctx.settings``."""

    pretrain_eval_periods: Int = Field(
        ge=1, le=10_000,
        description="periods the preliminary agent's error is measured over")
    segment_periods: Int = Field(ge=1, le=10_000, description="periods of each test segment (no wind, wind, no wind)")
    transient_periods: Int = Field(ge=0, le=10_000, description="first periods of each segment left out")

    @model_validator(mode="after")
    def _segment_after_transient(self) -> Self:
        if not self.transient_periods < self.segment_periods:
            raise rule_broken(self, "transient_periods < segment_periods",
                              "each test segment keeps periods after its transient")
        return self


class LissajousBifurcationSettings(SwitchingTrainingSettings):
    """What ``lissajous-bifurcation`` reads from ``ctx.settings``."""

    transient_periods: Int = Field(ge=0, le=10_000, description="periods run under each wind before recording")
    record_periods: Int = Field(ge=2, le=10_000, description="periods recorded under each wind")


class LissajousTimingSettings(SwitchingTrainingSettings):
    """What ``lissajous-timing`` reads from ``ctx.settings``."""

    settle_periods: Int = Field(ge=1, le=10_000, description="periods on the first curve before the switch")
    run_periods: Int = Field(ge=1, le=100_000, description="periods run after the switch")
    last_periods: Int = Field(
        ge=1, le=10_000,
        description="last periods compared (to the reference row and the target)")

    @model_validator(mode="after")
    def _last_within_run(self) -> Self:
        if not self.last_periods <= self.run_periods:
            raise rule_broken(self, "last_periods <= run_periods", "the last periods compared are periods of the run")
        return self


class ClosedLoopSchemesSettings(ExperimentSettings):
    """What ``closed-loop-schemes`` reads from ``ctx.settings``."""

    n_curves: Int = Field(ge=1, le=3, description="curves of the supplement's table (the first N of 3)")
    n_seeds: Int = Field(ge=1, le=1000, description="seeds per curve (seeds 1000·SEED, 1000·SEED + 1, …; the paper: 5)")
    pretrain_time: Number = Field(ge=0, le=100_000, description="preliminary open-loop training [s]")
    add_time: Number = Field(ge=0, le=100_000, description="additional closed-loop training of schemes 2 and 3 [s]")
    eval_periods: Int = Field(ge=1, le=10_000, description="periods the closed loop's error is measured over")
    scheme1_time: Number = Field(ge=0, le=100_000, description="closed-loop training of scheme 1 from scratch [s]")

    @model_validator(mode="after")
    def _jobs_bounded(self) -> Self:
        if not self.n_curves * self.n_seeds <= 3000:
            raise rule_broken(self, "n_curves * n_seeds <= 3000", "a job per curve and seed")
        return self


# -- locomotion: the agent settings alike in all three (one base model), so they share agents -----------------------

class LocomotionAgentSettings(ExperimentSettings):
    """How a locomotion experiment trains and evaluates its agents: the settings all three share, first in each, so
    that equal values give the same agents (their own settings follow these)."""

    sim_time: Number = Field(ge=0, le=100_000, description="forward training of each agent [s] (the paper: 1000 s)")
    warmup_windows: Int = Field(
        ge=0, le=100_000,
        description="untrained 200-step windows before the training (the paper: 100)")
    fit_time: Number = Field(
        ge=0, le=10_000,
        description="open-loop run the FL is fitted on [s] (its middle 60 % used)")
    eval_time: Number = Field(ge=0, le=10_000, description="open- and closed-loop runs whose speeds are compared [s]")
    handover_time: Number = Field(ge=0, le=1000, description="the transition variant's blend from SWG to FL [s]")
    gait_time: Number = Field(ge=0, le=1000, description="stored gait for the figure [s]")
    projection: Str = Field(
        description="training.projection of the agents: clamp (a negative k, d or l set to 0, the paper) or reset "
        "(set to 0.1, the authors' code)")
    config_overrides: tuple[Str, ...] = Field(
        description="further key=value overrides of the agents' training config (config/locomotion_forward.yaml), "
        "e.g. body.integrator=published")

    @model_validator(mode="after")
    def _gait_within_eval(self) -> Self:
        if not self.gait_time <= self.eval_time:
            raise rule_broken(self, "gait_time <= eval_time",
                              "the stored gait is cut from the open-loop evaluation run")
        return self


class LocomotionClosedLoop20Settings(LocomotionAgentSettings):
    """What ``locomotion-closed-loop-20`` reads from ``ctx.settings``."""

    n_agents: Int = Field(ge=1, le=1000, description="agents (seeds 1000·SEED, 1000·SEED + 1, …; the paper: 20)")



class LocomotionPerturbationVariant(VariantSettings):
    """A named variant (protocol) of ``locomotion-perturbation``."""

    authors_draw: Bool = Field(
        description="the authors' draw: positions N(0, (σ·P/8)²), velocities N(0, (σ·S)²), P the body's x-extent, S "
        "the range of its x-velocities (false: the paper's positions N(0, σ²) [m])")


class LocomotionPerturbationSettings(LocomotionAgentSettings):
    """What ``locomotion-perturbation`` reads from ``ctx.settings``."""

    variant_model: ClassVar[type[VariantSettings] | None] = LocomotionPerturbationVariant

    n_agents: Int = Field(ge=1, le=1000, description="agents trained (seeds 1000·SEED, 1000·SEED + 1, …)")
    n_noise: Int = Field(ge=1, le=10_000, description="random perturbation patterns per σ (the paper: 100)")
    before_time: Float = Field(
        ge=0, le=10_000,
        description="run before the perturbation, whose speed is the reference [s]")
    after_time: Float = Field(
        ge=0, le=10_000,
        description="run after the perturbation, whose late speed is compared [s]")
    max_agents: Int = Field(ge=1, le=1000, description="most agents (whose closed loop succeeded) perturbed")



class LocomotionHeadwindVariant(VariantSettings):
    """A named variant (protocol) of ``locomotion-headwind``."""

    wind_force: Float = Field(ge=-1000, le=0, description="headwind F_wind while it blows [N] (< 0)")
    wind_period: Annotated[Float, Field(ge=0, le=10_000)] | None = Field(
        description="calm + windy period [s] (null: the scale's wind_period)")
    lr: tuple[Annotated[Float, Field(ge=0, le=1_000_000)], ...] = Field(
        min_length=5, max_length=5,
        description="learning rates k, d, l, A, φ of the switching training")
    lr_decay: Bool = Field(description="every rate ÷10 at 80 % and 90 % of the windows when there are more than 1,000")


class LocomotionHeadwindSettings(LocomotionAgentSettings):
    """What ``locomotion-headwind`` reads from ``ctx.settings``."""

    variant_model: ClassVar[type[VariantSettings] | None] = LocomotionHeadwindVariant

    switching_time: Number = Field(ge=0, le=300_000, description="additional training under the periodic headwind [s]")
    wind_period: Float = Field(ge=0, le=10_000, description="period of the headwind's on/off cycle [s]")
    eval_periods: Int = Field(ge=1, le=10_000, description="wind periods of the evaluation run")
    sweep_time: Float = Field(ge=0, le=10_000, description="run per wind value of the speed-vs-F_wind sweep [s]")



# -- every experiment's model --------------------------------------------------------------------------------------

#: each experiment's settings model (experiment name → model), in the paper's order
SETTINGS_MODELS: dict[str, type[ExperimentSettings]] = {
    "mnist-drawing": MnistDrawingSettings,
    "mnist-pca": MnistPcaSettings,
    "mnist-labelmap": MnistLabelmapSettings,
    "mnist-specific100": MnistSpecific100Settings,
    "mnist-readout": MnistReadoutSettings,
    "narma-emulation": NarmaEmulationSettings,
    "narma-ipc": NarmaIpcSettings,
    "memory-task": MemoryTaskSettings,
    "target-ipc": TargetIpcSettings,
    "msdn-nonlinearity": MsdnNonlinearitySettings,
    "lissajous-closed-loop": LissajousClosedLoopSettings,
    "lissajous-perturbation": LissajousPerturbationSettings,
    "lissajous-switching": LissajousSwitchingSettings,
    "lissajous-bifurcation": LissajousBifurcationSettings,
    "lissajous-timing": LissajousTimingSettings,
    "closed-loop-schemes": ClosedLoopSchemesSettings,
    "locomotion-closed-loop-20": LocomotionClosedLoop20Settings,
    "locomotion-perturbation": LocomotionPerturbationSettings,
    "locomotion-headwind": LocomotionHeadwindSettings,
}
