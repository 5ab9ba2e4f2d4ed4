"""Resuming a residual training from a checkpoint (``python -m eval.residual --resume``): what changed since
the run it comes from (read from that run's ``config.json``), and the replay buffer's rewards relabelled for a new
action-rate weight (docs/design.md section 6)."""

from __future__ import annotations

import json
from pathlib import Path

from stable_baselines3.common.buffers import ReplayBuffer

from controllers.residual import ResidualConfig
from controllers.residual.env import action_rate_penalty
from controllers.residual.features import PREVIOUS_ACTION


def resume_mismatch(checkpoint: Path, scenario: str, base: str) -> str | None:
    """What differs between the run a checkpoint comes from and a resumed run's ``scenario`` and ``base``
    (as a sentence), from the ``config.json`` of its run folder; None when nothing differs or no record is
    found (a checkpoint outside a run folder)."""
    for folder in (checkpoint.parent, checkpoint.parent.parent):
        record = folder / "config.json"
        if record.is_file():
            arguments = json.loads(record.read_text())["config"]["arguments"]
            trained = {"scenario": arguments.get("scenario"), "base": arguments.get("base", "mid_f_rls")}
            resumed = {"scenario": scenario, "base": base}
            changed = [f"{key} {trained[key]} -> {resumed[key]}" for key in trained if trained[key] != resumed[key]]
            return f"{checkpoint} was trained with another setting: {', '.join(changed)}" if changed else None
    return None


REWARD_FIELDS = ("reward_scale", "torque_weight", "action_rate_weight", "plant_torque_weight")
"""The :class:`ResidualConfig` fields a replay buffer's rewards were computed with."""


def trained_config(checkpoint: Path) -> ResidualConfig | None:
    """The residual settings of the run a checkpoint comes from, from the ``config.json`` of its run folder (fields
    its record predates take their defaults); None when no record is found (a checkpoint outside a run folder)."""
    for folder in (checkpoint.parent, checkpoint.parent.parent):
        record = folder / "config.json"
        if record.is_file():
            return ResidualConfig.from_dict(json.loads(record.read_text())["config"]["residual_config"])
    return None


def reward_change(checkpoint: Path, config: ResidualConfig) -> str | None:
    """What of the reward (:data:`REWARD_FIELDS`) differs between the run a checkpoint comes from and ``config``,
    as a sentence; None when nothing differs or no record is found."""
    trained = trained_config(checkpoint)
    if trained is None:
        return None
    changed = [
        f"{key} {getattr(trained, key)} -> {getattr(config, key)}"
        for key in REWARD_FIELDS
        if getattr(trained, key) != getattr(config, key)
    ]
    return f"the reward changed since {checkpoint}: {', '.join(changed)}" if changed else None


def relabelable(trained: ResidualConfig, config: ResidualConfig) -> bool:
    """Whether a replay buffer filled under ``trained`` can be relabelled for ``config``: of the reward
    (:data:`REWARD_FIELDS`) and the residual's scale only ``action_rate_weight`` changed. The other terms depend on
    the plant's response, which a buffer does not keep."""
    fixed = [key for key in (*REWARD_FIELDS, "residual_limit") if key != "action_rate_weight"]
    return all(getattr(trained, key) == getattr(config, key) for key in fixed)


def relabel_action_rate(buffer: ReplayBuffer, trained: ResidualConfig, config: ResidualConfig) -> None:
    """Recompute, in place, the action-rate term of the rewards in ``buffer`` (filled under ``trained``) for
    ``config``: the term is a function of a transition's action and of the previous action its observation holds
    (:data:`~controllers.residual.features.PREVIOUS_ACTION`), so the relabelled rewards are those the transitions
    would have had under ``config``, to float32 round-off.

    Raises:
        ValueError: if the buffer cannot be relabelled (:func:`relabelable`).
    """
    if not relabelable(trained, config):
        raise ValueError(
            f"only action_rate_weight can be relabelled in a replay buffer: it was filled under {trained}, not {config}"
        )
    filled = buffer.buffer_size if buffer.full else buffer.pos
    actions = buffer.actions[:filled]
    previous = buffer.observations[:filled, ..., PREVIOUS_ACTION]
    change = action_rate_penalty(actions, previous, config) - action_rate_penalty(actions, previous, trained)
    buffer.rewards[:filled] += (config.reward_scale * change).astype(buffer.rewards.dtype)
