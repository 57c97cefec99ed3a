"""Learner hyperparameters: pydantic models (unknown keys rejected) and the preset loader.

The numbers live in ``flashnav/presets/pipeline.yaml`` and ``{fastdsac,fastsac,fasttd3}.yaml`` (the
paper's appendix A as data, plus the CPU recipe's departures); these models only say what a valid value is, and carry no defaults for
anything a preset must state. ``load_hparams("fastdsac", "turtlebot2", "paper", {"batch_size": 512})``
returns a validated, frozen model.
"""

from __future__ import annotations

from typing import Any, Literal

from pydantic import Field, ValidationError, field_validator, model_validator

from flashnav.config_base import Strict, error_lines
from flashnav.names import ALGORITHMS, PRECISIONS, RECIPES, check_name
from flashnav.presets import load_preset_file
from flashnav.yamlio import set_dotted

#: The wall-map encoder's 3 x 3 convolutions, (out channels, stride) each: the default of ``wall_map_convs`` (16, 32
#: and 32 channels, the last two with stride 2: each output sees 9 x 9 squares; flashnav/learn/wall_map.py).
WALL_MAP_CONVS: tuple[tuple[int, int], ...] = ((16, 1), (32, 2), (32, 2))


def bad_conv_layers(convs) -> list[list[int]]:
    """The layers of a wall-map CNN's ``(out channels, stride)`` list that are not (channels > 0, stride 1 or 2):
    the one rule of ``wall_map_convs`` and of :class:`flashnav.learn.wall_map.WallMapEncoder`."""
    return [list(c) for c in convs if c[0] <= 0 or c[1] not in (1, 2)]


class LearnerHParams(Strict):
    """Shared training-pipeline parameters (paper table "Shared off-policy training-pipeline
    parameters" and the per-algorithm tables' common rows)."""

    total_env_steps: int = Field(gt=0, description="environment transitions to collect (all envs together)")
    num_envs: int = Field(gt=0, description="parallel environments")
    updates_per_step: int = Field(gt=0, description="gradient updates per vector step (the paper's UTD)")
    learning_start: int = Field(ge=0, description="stored transitions before the first update")
    batch_size: int = Field(gt=0, description="transitions per gradient update")
    gamma: float = Field(gt=0, le=1, description="discount factor")
    tau: float = Field(gt=0, le=1, description="Polyak rate of the target critics, after every critic update")
    policy_frequency: int = Field(ge=1, description="actor update every k-th critic update")
    actor_lr: float = Field(gt=0, description="actor AdamW learning rate")
    critic_lr: float = Field(gt=0, description="critic AdamW learning rate")
    weight_decay: float = Field(ge=0, description="AdamW decoupled weight decay (actor and critics)")
    betas: tuple[float, float] = Field(description="AdamW (beta1, beta2)")
    actor_hidden: tuple[int, ...] = Field(min_length=1, description="actor hidden layer widths")
    critic_hidden: tuple[int, ...] = Field(min_length=1, description="critic hidden layer widths")
    # The three below default to "off" only so that run configs written before they existed read back
    # (RunSpec.from_dict); every preset states them (pipeline.yaml).
    layer_norm: bool = Field(False, description="LayerNorm before each hidden activation (actor and critics)")
    policy_averaging: float = Field(0.0, ge=0, le=1, description="Polyak rate, after every actor step, of the evaluated and exported policy's weights towards the trained actor (0 = the trained actor itself)")
    obs_norm: bool = Field(False, description="running mean/std normalisation of the IPAPRec features, updated from replay batches")
    n_step: int = Field(1, ge=1, description="rewards summed per sampled transition before bootstrapping (n-step returns; 1 = one-step, the references' num_steps default; docs/learners.md S12)")
    precision: Literal[PRECISIONS] = Field(  # type: ignore[valid-type]
        "float32", description="the learner updates' arithmetic: float32; bf16 = each update under torch.autocast(bfloat16) (matrix products in bf16, weights, state and targets float32), which pays only where the hardware multiplies bf16 natively (AVX-512 BF16 / AMX CPUs, GPUs); auto = bf16 there, float32 elsewhere, resolved and recorded when a run is set up (docs/learners.md S9)")
    lr_final_ratio: float = Field(1.0, ge=0, le=1, description="actor and critic learning rates at the end of the run's env-step budget, as a fraction of actor_lr / critic_lr: a cosine decay over the budget (1 = constant, the paper and the references' default; docs/learners.md S12)")
    late_batch_size: int = Field(0, ge=0, description="transitions per gradient update from late_from of the run's env-step budget on (0 = batch_size throughout, the paper and the references; docs/learners.md S17)")
    late_from: float = Field(0.5, ge=0, le=1, description="with late_batch_size: the fraction of the run's env-step budget (budget.max_env_steps) from which updates draw late_batch_size transitions")
    mirror: float = Field(0.0, ge=0, le=1, description="share of each replay batch reflected left-right (the scan reversed, goal angle, turn rates and robot-frame y negated; the twin transition of the mirrored map: flashnav/learn/mirror.py); 0 = off, the paper and the references")
    wall_shift: int = Field(0, ge=0, description="random shift of the wall map (observation.wall_map) in each replay batch, as in DrQ: every row's map, observation and next observation each, moves by up to this many squares along each axis, uncovered squares 0 (flashnav/learn/wall_shift.py); 0 = off")
    wall_map_convs: tuple[tuple[int, int], ...] = Field(WALL_MAP_CONVS, min_length=1, description="the wall map's CNN (observation.wall_map; flashnav/learn/wall_map.py): its 3 x 3 convolutions in order, [out channels, stride] each, stride 1 or 2 (padding 1); more layers see farther across the map (each layer adds 2 x the product of the strides before it to the squares one output sees a side); the default [[16, 1], [32, 2], [32, 2]] sees 9 x 9 squares")
    noise_color: float | tuple[float, ...] = Field(0.0, description="exponent beta of the collection noise's power spectrum 1/f^beta along the steps, one for every action or a list of one per action (e.g. [0, 1]: white forward speed, pink turn rate); each in [0, 2] (0 = white: independent draws, the paper and the references; 1 = pink; 2 = red); each draw stays N(0, 1), only successive draws are correlated (flashnav/learn/noise.py, docs/learners.md S14)")
    goal_sincos: bool = Field(False, description="the actor and critics see the goal angle as (sin, cos) instead of angle / pi: continuous where the angle wraps from pi to -pi (the goal straight behind); the observation and the exported policy's input are unchanged; False = the paper's feature (docs/learners.md S18)")
    action_headroom: float = Field(1.0, ge=1, le=2, description="the robot's action is clamp(k tanh(mu), -1, 1) with this k, in training, evaluation and the exported policy: the action bounds (top speed, top turn rate) are reached at |tanh| = 1/k instead of only in the limit; the critics see the clamped action; 1 = the paper's tanh(mu) (docs/learners.md S19)")
    deterministic_envs: float = Field(0.0, ge=0, lt=1, description="share of the environment slots (the last round(share * num_envs)) that collect with the deterministic action, tanh(mu) - the policy that is evaluated and exported - instead of an exploration draw; their transitions enter the replay like the others' (the exploration draws are still made, so the other slots' noise is unchanged); 0 = every slot explores, the paper and the references (docs/learners.md S25)")
    actor_out_init_std: float = Field(0.01, ge=0, description="std of the normal draw of the actor's output-layer weights (bias 0); 0 = the hidden layers' PyTorch-default uniform draw, as the FastDSAC reference (docs/learners.md D1)")
    env_steps_per_sync: int = Field(ge=1, description="vector steps between collector-actor weight syncs")
    max_grad_norm: float = Field(ge=0, description="global gradient-norm clip (0 = off)")
    buffer_size: int = Field(gt=0, description="replay capacity, transitions (all envs together)")
    eval_every: int = Field(ge=1, description="evaluate every k vector steps")

    @model_validator(mode="after")
    def _check_shared(self):
        if not all(0 <= b < 1 for b in self.betas):
            raise ValueError(f"betas must lie in [0, 1), got {self.betas}")
        colours = (self.noise_color,) if isinstance(self.noise_color, (int, float)) else self.noise_color
        if not colours or not all(0 <= b <= 2 for b in colours):
            raise ValueError(f"noise_color must be an exponent in [0, 2], or a list of one per action, got {self.noise_color}")
        if min(self.actor_hidden + self.critic_hidden) <= 0:
            raise ValueError("hidden layer widths must be > 0")
        if self.learning_start > self.buffer_size:  # the replay never holds that many: no update would ever run
            raise ValueError(f"learning_start ({self.learning_start}) must be <= buffer_size ({self.buffer_size}): "
                             f"updates start once the replay holds learning_start transitions, and it holds at most "
                             f"about buffer_size")
        return self

    @field_validator("wall_map_convs")
    @classmethod
    def _check_convs(cls, convs):
        bad = bad_conv_layers(convs)
        if bad:
            raise ValueError(f"every layer is [out channels > 0, stride 1 or 2], got {bad} in "
                             f"{[list(c) for c in convs]}")
        return convs

    def batch_size_at(self, progress: float) -> int:
        """Transitions per update at ``progress`` (the fraction of the run's env-step budget done):
        ``late_batch_size`` from ``late_from`` on when it is set, else ``batch_size``."""
        return self.late_batch_size if self.late_batch_size and progress >= self.late_from else self.batch_size


def _ordered(name: str, pair: tuple[float, float], strict: bool = False) -> None:
    lo, hi = pair
    if lo > hi or (strict and lo == hi):
        raise ValueError(f"{name} must be (min, max) with min {'<' if strict else '<='} max, got ({lo}, {hi})")


class FastTD3HParams(LearnerHParams):
    """Paper table "FastTD3 hyperparameters"."""

    algorithm: Literal["fasttd3"] = "fasttd3"
    target_noise: float = Field(ge=0, description="target policy smoothing noise std (action units)")
    noise_clip: float = Field(ge=0, description="target policy smoothing noise clip")
    collection_noise: tuple[float, float] = Field(description="per-env exploration std range (min, max)")
    num_atoms: int = Field(ge=2, description="C51 atoms K")
    v_min: float = Field(description="C51 support lower end (return units)")
    v_max: float = Field(description="C51 support upper end (return units)")

    @model_validator(mode="after")
    def _check(self):
        _ordered("collection_noise", self.collection_noise)
        _ordered("(v_min, v_max)", (self.v_min, self.v_max), strict=True)
        if self.collection_noise[0] < 0:
            raise ValueError("collection_noise must be >= 0")
        return self


class FastSACHParams(LearnerHParams):
    """Paper table "FastSAC hyperparameters"."""

    algorithm: Literal["fastsac"] = "fastsac"
    alpha_lr: float = Field(gt=0, description="temperature learning rate")
    alpha_init: float = Field(gt=0, description="initial entropy temperature alpha")
    target_entropy_ratio: float = Field(description="target entropy = -ratio * action_dim (nats)")
    num_atoms: int = Field(ge=2, description="C51 atoms K")
    v_min: float = Field(description="C51 support lower end (return units)")
    v_max: float = Field(description="C51 support upper end (return units)")
    log_std_min: float = Field(description="actor log sigma lower bound")
    log_std_max: float = Field(description="actor log sigma upper bound")
    mean_action_q: float = Field(0.0, ge=0, description="weight of a second actor objective, the critics' value at the deterministic action tanh(mu) - the action that is evaluated and exported - beside the sampled action's (0 = off, the paper and the references; docs/learners.md S15)")

    @model_validator(mode="after")
    def _check(self):
        _ordered("(v_min, v_max)", (self.v_min, self.v_max), strict=True)
        _ordered("(log_std_min, log_std_max)", (self.log_std_min, self.log_std_max), strict=True)
        return self


class FastDSACHParams(LearnerHParams):
    """Paper table "FastDSAC hyperparameters"."""

    algorithm: Literal["fastdsac"] = "fastdsac"
    std_ema: float = Field(gt=0, le=1, description="running-std EMA rate tau_b")
    reward_scale: float = Field(gt=0, description="rewards are multiplied by this in the critic target")
    temperature: float = Field(gt=0, description="DEM allocation softmax temperature T")
    scale_range: tuple[float, float] = Field(description="per-env DEM collection scale range (min, max)")
    cdq: bool = Field(description="clipped double Q (argmin of target means) instead of the mean of both")
    log_std_min: float = Field(description="actor log sigma lower bound")
    log_std_max: float = Field(description="actor log sigma upper bound")
    huber_delta: float = Field(gt=0, description="Huber delta of the critic loss (return units)")
    alpha_lr: float = Field(gt=0, description="temperature learning rate")
    alpha_init: float = Field(gt=0, description="initial entropy temperature alpha")
    target_entropy_ratio: float = Field(description="target entropy = -ratio * action_dim (nats)")
    mean_action_q: float = Field(0.0, ge=0, description="weight of a second actor objective, the critics' value at the deterministic action tanh(mu) - the action that is evaluated and exported - beside the sampled action's (0 = off, the paper and the references; docs/learners.md S15)")
    risk_cvar: float = Field(1.0, gt=0, le=1, description="the actor climbs the CVaR at this level of each critic's Gaussian return, mu - sigma pdf(q)/level with q the level's normal quantile, instead of its mean: a risk-averse policy below 1 (1 = the mean, the paper and the references; docs/learners.md S24)")

    @model_validator(mode="after")
    def _check(self):
        _ordered("scale_range", self.scale_range)
        _ordered("(log_std_min, log_std_max)", (self.log_std_min, self.log_std_max), strict=True)
        if self.scale_range[0] <= 0:
            raise ValueError("scale_range must be > 0")
        return self


MODELS: dict[str, type[LearnerHParams]] = {
    "fastdsac": FastDSACHParams, "fastsac": FastSACHParams, "fasttd3": FastTD3HParams,
}
AnyHParams = FastDSACHParams | FastSACHParams | FastTD3HParams


def override_section(key: str) -> str | None:
    """``algo`` or ``robot`` where ``key`` names a learner hyperparameter or a robot preset section, else None
    (the hint for an override written without its section: ``batch_size=512``)."""
    from flashnav.config import RobotPreset

    if any(key in model.model_fields for model in MODELS.values()):
        return "algo"
    return "robot" if key in RobotPreset.model_fields else None


def load_hparams(algorithm: str, robot: str, recipe: str = "paper",
                 overrides: dict[str, Any] | None = None) -> AnyHParams:
    """Validated hyperparameters for ``algorithm`` / ``robot`` / ``recipe`` with dotted-key overrides.

    ``recipe``: one of ``flashnav.names.RECIPES`` (each described in ``names.RECIPE_HELP``; a recipe's
    ``base`` is laid first). The values are the layers of ``flashnav/presets/pipeline.yaml`` and
    ``<algorithm>.yaml`` (order written in pipeline.yaml). Override keys name fields of the algorithm's model (``{"batch_size": 512,
    "betas": [0.9, 0.99]}``); an unknown key is an error that suggests the closest names.
    """
    check_name("algorithm", algorithm, ALGORITHMS)
    if recipe not in RECIPES:
        raise ValueError(f"unknown recipe {recipe!r}: use one of {', '.join(RECIPES)} "
                         "(resolve 'auto' from the device before calling)")
    data = dict(recipe_values(algorithm, robot, recipe))
    for key, value in (overrides or {}).items():
        set_dotted(data, key, value, known=MODELS[algorithm], what="algo override")
    try:
        return MODELS[algorithm].model_validate(data)
    except ValidationError as exc:
        problems = "; ".join(error_lines(exc, "algo"))
        raise ValueError(f"{algorithm}.yaml [{recipe}.{robot}] with overrides {overrides or {}}: {problems}") from None


def recipe_values(algorithm: str, robot: str, recipe: str) -> dict[str, Any]:
    """The plain values of one recipe, its layers merged (no validation, no overrides)."""
    pipeline, own = load_preset_file("pipeline"), load_preset_file(algorithm)
    if robot not in (own.get("paper") or {}):
        have = sorted(k for k in (own.get("paper") or {}) if k != "shared")
        raise ValueError(f"{algorithm}.yaml: no recipe for robot {robot!r}; have {', '.join(have) or 'none'} (a "
                         "preset's `name:` picks its recipe: a robot of your own trains with the hyperparameters "
                         "of the one it is closest to when its preset keeps that robot's name, or with a recipe "
                         f"section for {robot!r} added to {algorithm}.yaml)")
    layers = [pipeline.get("shared"), pipeline.get(robot), own["paper"].get("shared"), own["paper"][robot]]
    chain: list[str] = []  # the recipe after the recipes it is based on (``base:``), paper excluded
    while recipe != "paper":
        if recipe in chain:
            raise ValueError(f"{algorithm}.yaml: recipe {chain[0]!r} is based on {recipe!r}, which is based on "
                             f"it: the bases {' -> '.join(reversed(chain))} -> {recipe} go round in a circle")
        chain.insert(0, recipe)
        recipe = (own.get(recipe) or {}).get("base", "paper")
    for name in chain:
        if name not in own:
            raise ValueError(f"{algorithm}.yaml has no {name!r} recipe (it has: "
                             f"{', '.join(k for k in own if isinstance(own[k], dict))})")
        section = own[name] or {}
        if robot not in section:
            raise ValueError(f"{algorithm}.yaml: no {name!r} recipe for robot {robot!r}")
        layers += [section.get("shared"), section[robot]]
    data: dict[str, Any] = {}
    for layer in layers:
        data.update(layer or {})
    return data


def paper_budget(algorithm: str, robot: str) -> int | None:
    """The paper's environment-step budget of ``algorithm`` on ``robot``: its ``paper`` recipe's
    ``total_env_steps`` (appendix A: 200,704 on TurtleBot2; 401,408 / 501,760 / 602,112 for FastDSAC /
    FastSAC / FastTD3 on Go2). None for a robot the paper has no recipe for."""
    try:
        return int(recipe_values(algorithm, robot, "paper")["total_env_steps"])
    except (ValueError, KeyError):
        return None
