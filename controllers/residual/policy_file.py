"""The residual policy file: an SB3 zip with the settings and the base controller it was trained with.

:func:`save_residual_policy` adds a member ``residual.json`` to the SB3 zip: the algorithm, the feature
layout version, the :class:`~controllers.residual.config.ResidualConfig` and the :class:`BaseSetup` of the
base controller (identified parameters, estimator, tare). :func:`load_residual_controller` rebuilds the
whole 1 kHz controller from the file alone. SB3 (and torch) are imported only when a model is loaded.
"""

from __future__ import annotations

import json
import math
import zipfile
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal, NamedTuple

import numpy as np
from numpy.typing import NDArray

from controllers.base import Controller
from controllers.dynamics import ModelParameters
from controllers.feedforward import controller_name, model_controller
from controllers.payload import FRICTION_VELOCITY
from controllers.residual.config import ResidualConfig
from controllers.residual.controller import ResidualController
from controllers.residual.features import FEATURE_VERSION, ResidualFeatures
from delta_env.geometry import NOMINAL_GEOMETRY, NOMINAL_MASSES, DeltaGeometry, DeltaMasses

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
    base: BaseSetup | None = None,
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
        "base": None if base is None else base.to_dict(),
        "extra": extra or {},
    }
    with zipfile.ZipFile(path, "a") as archive:
        archive.writestr(METADATA_NAME, json.dumps(metadata, indent=2))
    return path


_LEGACY_BASE = {"forearm_rods": False, "regressor": "filtered", "friction_velocity": 0.1, "drive_lag": None}
"""The base settings of policy files written before these keys existed: the lumped model, the causal
filter, a 0.1 rad/s friction band and no drive-lag lead."""


@dataclass(frozen=True)
class BaseSetup:
    """What the default base controller was built from: model, identified parameters, estimator and tare.

    Attributes:
        parameters: Identified parameters of the model.
        tare: Apparent payload of the empty gripper (kg).
        forearm_rods: MId+F+R (True) or the paper's lumped MId+F.
        regressor: Joint states of the payload estimator.
        friction_velocity: The estimator's friction band (rad/s).
        geometry: Lengths (m) of the robot the parameters were identified on.
        masses: Datasheet masses (kg) of that robot.
        drive_lag: Identified drive lag T (s) per joint that the feedforward leads; None: no lead.
    """

    parameters: ModelParameters
    tare: float = 0.0
    forearm_rods: bool = True
    regressor: Literal["smoothed", "filtered", "reference"] = "smoothed"
    friction_velocity: float = FRICTION_VELOCITY
    geometry: DeltaGeometry = NOMINAL_GEOMETRY
    masses: DeltaMasses = NOMINAL_MASSES
    drive_lag: tuple[float, float, float] | None = None

    def controller(self) -> Controller:
        """A fresh base controller with these settings: model feedforward (leading the drive lag when known)
        + PD with the payload RLS."""
        return model_controller(
            self.parameters,
            forearm_rods=self.forearm_rods,
            regressor=self.regressor,
            tare=self.tare,
            friction_velocity=self.friction_velocity,
            geometry=self.geometry,
            masses=self.masses,
            drive_lag=self.drive_lag,
        )

    @property
    def name(self) -> str:
        """The base controller's label, e.g. ``"MId+F+R+RLS+lag+PD"``."""
        return controller_name(self.forearm_rods, estimates_payload=True, leads_lag=self.drive_lag is not None)

    def to_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "parameters": asdict(self.parameters),
            "tare": self.tare,
            "forearm_rods": self.forearm_rods,
            "regressor": self.regressor,
            "friction_velocity": self.friction_velocity,
            "geometry": asdict(self.geometry),
            "masses": asdict(self.masses),
            "drive_lag": None if self.drive_lag is None else list(self.drive_lag),
        }

    @classmethod
    def from_dict(cls, values: dict[str, Any]) -> BaseSetup:
        values = {**_LEGACY_BASE, **values}
        parameters = values["parameters"]
        return cls(
            parameters=ModelParameters(
                rho1=parameters["rho1"],
                rho2=parameters["rho2"],
                viscous=tuple(parameters["viscous"]),
                coulomb=tuple(parameters["coulomb"]),
            ),
            tare=float(values["tare"]),
            forearm_rods=bool(values["forearm_rods"]),
            regressor=values["regressor"],
            friction_velocity=float(values["friction_velocity"]),
            geometry=DeltaGeometry(**values.get("geometry", asdict(NOMINAL_GEOMETRY))),
            masses=DeltaMasses(**values.get("masses", asdict(NOMINAL_MASSES))),
            drive_lag=None if values["drive_lag"] is None else _drive_lag(values["drive_lag"]),
        )


def _drive_lag(values: Any) -> tuple[float, float, float]:
    """Three finite, non-negative time constants (s) from a policy file."""
    lags = tuple(float(v) for v in values)
    if len(lags) != 3 or not all(math.isfinite(v) and v >= 0.0 for v in lags):
        raise ValueError(f"drive_lag must be 3 finite time constants >= 0 s, got {values!r}")
    return lags


@dataclass(frozen=True)
class ResidualPolicy:
    """A loaded residual policy: the SB3 model, the settings and the base it was trained with."""

    model: BaseAlgorithm
    config: ResidualConfig
    algo: str
    base: BaseSetup | None
    metadata: dict[str, Any]
    layers: tuple[tuple[NDArray[np.float32], NDArray[np.float32]], ...] | None = None
    """The deterministic actor as float32 (weight, bias) pairs of its Linear layers (ReLU between them, tanh
    after the last), when it is that plain MLP (:func:`actor_layers`); None runs the torch modules."""

    def __call__(self, observation: NDArray[np.float32]) -> NDArray[np.float32]:
        """The deterministic action (mean of the policy) for one observation ``(43,)`` or a batch ``(N, 43)``.

        For SAC and TQC (without gSDE) the arithmetic of SB3's ``predict(observation, deterministic=True)`` without
        its per-call input checks and distribution objects, which cost three times the network: tanh of the
        actor's mean, unscaled to the action space. A plain MLP actor runs as NumPy matrix products on its
        float32 weights, as a controller would deploy it: the torch call costs about four times the
        arithmetic at one observation; the actions agree with torch's to float32 round-off.
        """
        policy = self.model.policy
        if self.algo not in SQUASHED_GAUSSIAN_ACTORS or policy.actor.use_sde:
            action, _ = self.model.predict(observation, deterministic=True)
            return action
        if self.layers is not None:
            hidden = np.asarray(observation, dtype=np.float32)
            last = len(self.layers) - 1
            for index, (weight, bias) in enumerate(self.layers):
                hidden = hidden @ weight.T + bias
                if index < last:
                    np.maximum(hidden, 0.0, out=hidden)
            return policy.unscale_action(np.tanh(hidden))
        import torch

        actor = policy.actor
        with torch.no_grad():
            features = actor.features_extractor(torch.as_tensor(observation).reshape(-1, ResidualFeatures.size))
            action = policy.unscale_action(torch.tanh(actor.mu(actor.latent_pi(features))).numpy())
        return action if np.ndim(observation) == 2 else action[0]


def actor_layers(model: BaseAlgorithm) -> tuple[tuple[NDArray[np.float32], NDArray[np.float32]], ...] | None:
    """The (weight, bias) float32 arrays of a SAC (or TQC) actor that is a plain MLP: flattened input, Linear and ReLU
    layers, a Linear mean; None for any other actor (PPO, gSDE, other activations or feature extractors)."""
    import torch
    from stable_baselines3.common.torch_layers import FlattenExtractor

    actor = getattr(model.policy, "actor", None)
    if actor is None or getattr(actor, "use_sde", True) or not isinstance(actor.features_extractor, FlattenExtractor):
        return None
    modules = [*actor.latent_pi, actor.mu]
    linear = modules[0::2]
    if not all(isinstance(m, torch.nn.Linear) for m in linear) or not all(
        isinstance(m, torch.nn.ReLU) for m in modules[1::2]
    ):
        return None
    return tuple(
        (m.weight.detach().numpy().astype(np.float32), m.bias.detach().numpy().astype(np.float32)) for m in linear
    )


class PolicySettings(NamedTuple):
    """What a policy file records beside the model: the settings, the algorithm, the base and all its metadata."""

    config: ResidualConfig
    algo: str
    base: BaseSetup | None
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
        base = None if metadata["base"] is None else BaseSetup.from_dict(metadata["base"])
        algo = metadata["algo"]
        if algo not in ALGORITHMS:
            raise ValueError(f"algo must be one of {ALGORITHMS}, got {algo!r}")
    except (KeyError, TypeError, ValueError) as error:
        raise ValueError(f"could not load the residual policy {path}: {error}") from error
    return PolicySettings(config, algo, base, metadata)


def load_residual_policy(path: str | Path = DEFAULT_POLICY_PATH) -> ResidualPolicy:
    """Load a policy written by :func:`save_residual_policy` (on the CPU).

    Raises:
        FileNotFoundError: if ``path`` does not exist.
        ValueError: if ``path`` is not a valid residual policy (corrupt zip, missing or incompatible
            settings, unreadable model); the message names the path.
    """
    settings = read_policy_settings(path)
    try:
        model = algorithm_class(settings.algo).load(path, device="cpu")
        model.policy.set_training_mode(False)
    except Exception as error:  # SB3 and torch raise many kinds on a damaged archive
        raise ValueError(f"could not load the residual policy {path}: {error}") from error
    expected = (ResidualFeatures.size,)
    if model.observation_space.shape != expected or model.action_space.shape != (3,):
        raise ValueError(
            f"{path}: policy spaces {model.observation_space.shape} -> {model.action_space.shape} do not match "
            f"the residual observation {expected} -> (3,)"
        )
    return ResidualPolicy(
        model=model,
        config=settings.config,
        algo=settings.algo,
        base=settings.base,
        metadata=settings.metadata,
        layers=actor_layers(model) if settings.algo in SQUASHED_GAUSSIAN_ACTORS else None,
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
    policy = load_residual_policy(path)
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


def shipped_base_setup(path: str | Path = DEFAULT_POLICY_PATH) -> BaseSetup:
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
            "pass base= (e.g. controllers.feedforward.model_controller with parameters from `python -m eval.identify`)"
        ) from None
    if metadata.get("base") is None:
        raise ValueError(
            f"{path} records no base controller; pass base= (e.g. controllers.feedforward.model_controller with "
            "parameters from `python -m eval.identify`)"
        )
    try:
        return BaseSetup.from_dict(metadata["base"])
    except (KeyError, TypeError, ValueError) as error:
        raise ValueError(f"{path}: unreadable base controller settings: {error}") from error
