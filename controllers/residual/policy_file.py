"""The residual policy file: an SB3 zip with the settings and the base controller it was trained with.

:func:`save_residual_policy` adds a member ``residual.json`` to the SB3 zip: the algorithm, the feature
layout version, the :class:`~controllers.residual.config.ResidualConfig` and the :class:`PolicyBase` of the
base controller: its row and what it knew, the experiments' :class:`~controllers.setup.ControllerSetup` record
(identified parameters, drive lag, tare, gains, geometry and datasheet masses), written by the generic writer of
:mod:`delta_env.records` with its content hash. :func:`load_residual_controller` rebuilds the whole 1 kHz controller
from the file alone; files written before the record held a separate base record, which still loads. SB3 (and
torch) are imported only when a model is loaded: a controller reads a SAC actor without them
(:mod:`controllers.residual.actor`).
"""

from __future__ import annotations

import json
import zipfile
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from controllers.base import Controller
from controllers.feedforward import controller_name
from controllers.payload import FRICTION_VELOCITY
from controllers.residual.actor import MlpActor, model_actor, read_actor
from controllers.residual.config import ResidualConfig
from controllers.residual.controller import ResidualController
from controllers.residual.features import FEATURE_VERSION, ResidualFeatures
from controllers.setup import ESTIMATOR_REGRESSORS, MODEL_ROWS, ControllerSetup, model_row
from delta_env.records import content_hash

if TYPE_CHECKING:
    from stable_baselines3.common.base_class import BaseAlgorithm

DEFAULT_POLICY_PATH = Path(__file__).resolve().parent.parent / "policies" / "residual_sac.zip"
"""The shipped residual policy (SAC), resolved inside the package."""

METADATA_NAME = "residual.json"
"""Member of a policy zip that holds its :class:`ResidualConfig`, algorithm and feature version."""

ALGORITHMS = ("sac", "ppo", "tqc", "crossq")
"""Algorithm names: stable-baselines3's SAC and PPO, sb3-contrib's TQC and CrossQ."""

SQUASHED_GAUSSIAN_ACTORS = ("sac", "tqc")
"""Algorithms whose actor is SAC's (an MLP mean squashed by tanh): their deterministic action skips ``predict``."""


def algorithm_class(algo: str) -> type[BaseAlgorithm]:
    """The SB3 class of ``algo`` (one of :data:`ALGORITHMS`); SB3 (and sb3-contrib for TQC and CrossQ) is
    imported only when a policy is used."""
    if algo not in ALGORITHMS:
        raise ValueError(f"algo must be one of {ALGORITHMS}, got {algo!r}")
    if algo in ("sac", "ppo"):
        from stable_baselines3 import PPO, SAC

        return {"sac": SAC, "ppo": PPO}[algo]
    try:
        from sb3_contrib import TQC, CrossQ
    except ImportError as error:
        raise ImportError(f"algo {algo!r} needs sb3-contrib (pip install -e '.[rl]')") from error
    return {"tqc": TQC, "crossq": CrossQ}[algo]


def save_residual_policy(
    model: BaseAlgorithm,
    path: str | Path,
    config: ResidualConfig,
    algo: str,
    *,
    base: PolicyBase | None = None,
    extra: dict[str, Any] | None = None,
) -> Path:
    """Save an SB3 model with its residual settings inside the zip (member ``residual.json``).

    Args:
        model: The trained SAC or PPO model.
        path: Target ``.zip`` path.
        config: The settings the model was trained with.
        algo: One of :data:`ALGORITHMS`.
        base: The default base controller's setup it was trained on (None: a custom base).
        extra: JSON-serializable notes stored beside the settings (e.g. the training command).

    Returns:
        The path written.
    """
    algorithm_class(algo)
    path = Path(path)
    if path.suffix != ".zip":
        raise ValueError(f"a residual policy is a .zip file, got {path}")
    path.parent.mkdir(parents=True, exist_ok=True)
    model.save(path)
    metadata = {
        "algo": algo,
        "feature_version": FEATURE_VERSION,
        "config": asdict(config),
        "base": None if base is None else base.to_table(),
        "extra": extra or {},
    }
    with zipfile.ZipFile(path, "a") as archive:
        archive.writestr(METADATA_NAME, json.dumps(metadata, indent=2))
    return path


@dataclass(frozen=True)
class PolicyBase:
    """The base controller a policy was trained on: a built-in RLS row and what it knew.

    Attributes:
        key: Its row (a key of :data:`controllers.setup.ESTIMATOR_REGRESSORS`: the residual reads its payload
            estimate).
        setup: What it knew (:class:`~controllers.setup.ControllerSetup`: identified parameters, drive lag, its tare
            and empty moves, gains, geometry and datasheet masses), as every row of the experiments does.
    """

    key: str
    setup: ControllerSetup

    def __post_init__(self) -> None:
        if self.key not in ESTIMATOR_REGRESSORS:
            raise ValueError(f"a residual's base is one of {', '.join(ESTIMATOR_REGRESSORS)}, got {self.key!r}")

    def controller(self) -> Controller:
        """A fresh base controller: the row ``key`` built from ``setup`` (:func:`controllers.setup.model_row`)."""
        return model_row(self.key, self.setup)

    @property
    def name(self) -> str:
        """The base controller's label, e.g. ``"MId+F+R+RLS+lag+PD"``."""
        return controller_name(True, estimates_payload=True, leads_lag=MODEL_ROWS[self.key].leads_lag)

    def to_table(self) -> dict[str, Any]:
        """What a policy file stores: the key, the setup's table (:meth:`ControllerSetup.to_table`) and its content
        hash, which :meth:`from_table` checks."""
        setup = self.setup
        return {"name": self.name, "key": self.key, "setup": setup.to_table(), "setup_hash": setup.content_hash()}

    @classmethod
    def from_table(cls, values: dict[str, Any]) -> PolicyBase:
        """The base of a policy file's ``base`` table: the record of :meth:`to_table` (its hash checked), or the
        separate base record of the files written before it (:func:`_legacy_base`).

        Raises:
            ValueError: if the table is unreadable, its setup does not match its hash, or an old base is not a row
                of this version.
        """
        if "setup" not in values:
            return _legacy_base(values)
        table = values["setup"]
        # The record as written: its hash covers the fields of its day. A base written before the servo layer ran the
        # paper's PD; other fields added since take their defaults.
        written, recorded = content_hash(table), values.get("setup_hash")
        setup = ControllerSetup.from_table({"servo": "pd", **table}, "base.setup")
        if written != recorded:
            raise ValueError(
                f"base.setup hashes to {written}, not to the recorded setup_hash {recorded!r}: the record was "
                "edited or damaged"
            )
        return cls(values["key"], setup)


def _legacy_base(values: dict[str, Any]) -> PolicyBase:
    """The base of a policy file written before the base was a :class:`~controllers.setup.ControllerSetup`: its one
    parameter set (MId+F+R), tare, geometry, datasheet masses and drive lag (a lag means the lag row).

    Raises:
        ValueError: for a base no row of this version builds (the lumped forearms, the causal filter's regressor or
            another friction band, which the files before the rod model recorded).
    """
    regressor = values.get("regressor", "filtered")
    friction_velocity = float(values.get("friction_velocity", 0.1))
    if not values.get("forearm_rods", False) or regressor not in ("smoothed", "reference"):
        raise ValueError(
            f"the base {values.get('name')!r} (forearm_rods={values.get('forearm_rods', False)}, regressor "
            f"{regressor!r}) is no row of this version (MId+F+R with the smoothed or reference regressor): retrain "
            "the policy on a current base"
        )
    if friction_velocity != FRICTION_VELOCITY:
        raise ValueError(
            f"the base {values.get('name')!r} has a friction band of {friction_velocity} rad/s, the rows of this "
            f"version {FRICTION_VELOCITY} rad/s: retrain the policy on a current base"
        )
    lag = values.get("drive_lag")
    # a lag meant the lag row, which leads it; the reference regressor had no lag row
    leads_lag = lag is not None and regressor == "smoothed"
    key = next(key for key, row in MODEL_ROWS.items() if (row.regressor, row.leads_lag) == (regressor, leads_lag))
    table = {"mid": values["parameters"], "mid_f": values["parameters"], "mid_f_rods": values["parameters"]}
    # The lumped parameter sets are unknown to these files; the base row does not use them.
    for name in ("drive_lag", "geometry", "masses"):
        if values.get(name) is not None:
            table[name] = values[name]
    table["tares"] = {key: values["tare"]}
    table["servo"] = "pd"  # these files predate the servo layer
    return PolicyBase(key, ControllerSetup.from_table(table, "base"))


@dataclass(frozen=True)
class ResidualPolicy:
    """A loaded residual policy: the SB3 model (None when loaded for deployment), the settings and the base it was
    trained with."""

    model: BaseAlgorithm | None
    config: ResidualConfig
    algo: str
    base: PolicyBase | None
    metadata: dict[str, Any]
    actor: MlpActor | None = None
    """The deterministic actor as NumPy float32 layers when it is SAC's plain MLP (:mod:`controllers.residual.actor`);
    None runs the SB3 model."""

    def __call__(self, observation: NDArray[np.float32]) -> NDArray[np.float32]:
        """The deterministic action (mean of the policy) for one observation ``(43,)`` or a batch ``(N, 43)``.

        For SAC and TQC (without gSDE) the arithmetic of SB3's ``predict(observation, deterministic=True)`` without
        its per-call input checks and distribution objects, which cost three times the network: tanh of the
        actor's mean, unscaled to the action space. A plain MLP actor runs as NumPy matrix products on its
        float32 weights, as a controller would deploy it: the torch call costs about four times the
        arithmetic at one observation; the actions agree with torch's to float32 round-off.
        """
        if self.actor is not None:
            return self.actor(observation)
        policy = self.model.policy
        if self.algo not in SQUASHED_GAUSSIAN_ACTORS or policy.actor.use_sde:
            action, _ = self.model.predict(observation, deterministic=True)
            return action
        import torch

        actor = policy.actor
        with torch.no_grad():
            features = actor.features_extractor(torch.as_tensor(observation).reshape(-1, ResidualFeatures.size))
            action = policy.unscale_action(torch.tanh(actor.mu(actor.latent_pi(features))).numpy())
        return action if np.ndim(observation) == 2 else action[0]


class PolicySettings(NamedTuple):
    """What a policy file records beside the model: the settings, the algorithm, the base and all its metadata."""

    config: ResidualConfig
    algo: str
    base: PolicyBase | None
    metadata: dict[str, Any]


def read_policy_settings(path: str | Path = DEFAULT_POLICY_PATH) -> PolicySettings:
    """The settings of a policy file, checked, without loading the model (no torch): what a caller needs to
    decide whether the policy fits a robot before paying for :func:`load_residual_policy`.

    Raises:
        FileNotFoundError: if ``path`` does not exist.
        ValueError: if the settings are missing, unreadable or of another feature version; the message names
            the path.
    """
    metadata = read_policy_metadata(path)
    try:
        if metadata["feature_version"] != FEATURE_VERSION:
            raise ValueError(f"feature version {metadata['feature_version']}, this code reads {FEATURE_VERSION}")
        config = ResidualConfig.from_dict(metadata["config"])
        base = None if metadata["base"] is None else PolicyBase.from_table(metadata["base"])
        algo = metadata["algo"]
        if algo not in ALGORITHMS:
            raise ValueError(f"algo must be one of {ALGORITHMS}, got {algo!r}")
    except (KeyError, TypeError, ValueError) as error:
        raise ValueError(f"could not load the residual policy {path}: {error}") from error
    return PolicySettings(config, algo, base, metadata)


def load_residual_policy(path: str | Path = DEFAULT_POLICY_PATH, *, deploy: bool = False) -> ResidualPolicy:
    """Load a policy written by :func:`save_residual_policy` (on the CPU).

    Args:
        path: The policy zip.
        deploy: Read only the deterministic actor, without SB3 or torch, when it is SAC's plain MLP
            (:func:`controllers.residual.actor.read_actor`; the model is then None); any other policy is loaded
            whole. What an episode needs: the evaluation's rows and a robot's controller.

    Raises:
        FileNotFoundError: if ``path`` does not exist.
        ValueError: if ``path`` is not a valid residual policy (corrupt zip, missing or incompatible
            settings, unreadable model); the message names the path.
    """
    settings = read_policy_settings(path)
    if deploy and settings.algo in SQUASHED_GAUSSIAN_ACTORS:
        actor = read_actor(path)
        if actor is not None:
            _check_spaces(path, (actor.layers[0][0].shape[1],), actor.low.shape)
            return ResidualPolicy(None, settings.config, settings.algo, settings.base, settings.metadata, actor)
    try:
        model = algorithm_class(settings.algo).load(path, device="cpu")
        model.policy.set_training_mode(False)
    except Exception as error:  # SB3 and torch raise many kinds on a damaged archive
        raise ValueError(f"could not load the residual policy {path}: {error}") from error
    _check_spaces(path, model.observation_space.shape, model.action_space.shape)
    return ResidualPolicy(
        model=model,
        config=settings.config,
        algo=settings.algo,
        base=settings.base,
        metadata=settings.metadata,
        actor=model_actor(model) if settings.algo in SQUASHED_GAUSSIAN_ACTORS else None,
    )


def _check_spaces(path: str | Path, observation: tuple[int, ...], action: tuple[int, ...]) -> None:
    """Raise ValueError (naming ``path``) unless the policy maps the residual observation to 3 torques."""
    expected = (ResidualFeatures.size,)
    if observation != expected or action != (3,):
        raise ValueError(
            f"{path}: policy spaces {observation} -> {action} do not match the residual observation {expected} -> (3,)"
        )


def load_residual_controller(
    path: str | Path = DEFAULT_POLICY_PATH, base: Controller | None = None, name: str | None = None
) -> Controller:
    """The shipped (or any saved) residual policy on top of ``base`` as a 1 kHz Controller.

    Args:
        path: A policy zip written by :func:`save_residual_policy`.
        base: The base controller the policy corrects. None rebuilds the base it was trained on from the
            file (model, identified parameters, estimator and tare), so no parameter file is needed.
        name: Row name; by default ``"<base name> + residual"``.

    Raises:
        FileNotFoundError: if ``path`` does not exist.
        ValueError: if the file is not a valid residual policy (the message names the path), or if
            ``base`` is None for a policy trained on a custom base.
    """
    policy = load_residual_policy(path, deploy=True)
    if base is None and policy.base is None:
        raise ValueError(f"{path} was trained on a custom base controller: pass base=")
    return residual_controller(policy, base, name)


def residual_controller(policy: ResidualPolicy, base: Controller | None = None, name: str | None = None) -> Controller:
    """A loaded residual policy on top of ``base`` as a 1 kHz Controller; one policy serves many controllers.

    Args:
        policy: From :func:`load_residual_policy`; it holds no episode state.
        base: The base controller the policy corrects. None rebuilds the base it was trained on.
        name: Row name; by default ``"<base name> + residual"``.

    Raises:
        ValueError: if ``base`` is None for a policy trained on a custom base.
    """
    if base is None:
        if policy.base is None:
            raise ValueError("the residual policy was trained on a custom base controller: pass base=")
        base = policy.base.controller()
    return ResidualController(base, policy, policy.config, name=name)


def read_policy_metadata(path: str | Path = DEFAULT_POLICY_PATH) -> dict[str, Any]:
    """The settings stored in a policy zip (member ``residual.json``), without loading the model (no torch).

    Raises:
        FileNotFoundError: if ``path`` does not exist.
        ValueError: if it is not a policy written by :func:`save_residual_policy`; the message names the path.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"residual policy file not found: {path}")
    try:
        with zipfile.ZipFile(path) as archive:
            return json.loads(archive.read(METADATA_NAME))
    except (zipfile.BadZipFile, KeyError, json.JSONDecodeError, UnicodeDecodeError) as error:
        raise ValueError(f"{path} is not a residual policy written by save_residual_policy: {error}") from error


def shipped_base_setup(path: str | Path = DEFAULT_POLICY_PATH) -> PolicyBase:
    """The base controller the policy at ``path`` was trained on: identified parameters and tare as recorded.

    The default env of ``DeltaPickPlaceResidual-v0`` runs this base, so making it needs no parameter file.

    Raises:
        FileNotFoundError: if ``path`` does not exist.
        ValueError: if it is not a policy file or its policy was trained on a custom base.
    """
    try:
        metadata = read_policy_metadata(path)
    except FileNotFoundError as error:
        raise FileNotFoundError(
            f"{error}: it holds the default base controller of DeltaPickPlaceResidual-v0; reinstall the package or "
            "pass base= (e.g. controllers.feedforward.model_controller with parameters from "
            "`python -m eval.identification`)"
        ) from None
    if metadata.get("base") is None:
        raise ValueError(
            f"{path} records no base controller; pass base= (e.g. controllers.feedforward.model_controller with "
            "parameters from `python -m eval.identification`)"
        )
    try:
        return PolicyBase.from_table(metadata["base"])
    except (KeyError, TypeError, ValueError) as error:
        raise ValueError(f"{path}: unreadable base controller settings: {error}") from error
