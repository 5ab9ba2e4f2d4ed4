"""The deterministic actor of a SAC or TQC policy as NumPy float32 matrix products: what a controller deploys.

:func:`model_actor` takes it from a loaded SB3 model; :func:`read_actor` reads it from a policy zip without SB3 or
torch. The zip's ``policy.pth`` is torch's zip serialization: a pickled state dict whose tensors point into raw
little-endian members ``<root>/data/<key>``, which a restricted unpickler turns into arrays. An actor is
deployable when it is SAC's plain MLP: the default policy class, a flat observation, ReLU between Linear layers
and tanh after the mean, no gSDE.
"""

from __future__ import annotations

import base64
import collections
import io
import itertools
import json
import pickle
import pickletools
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

if TYPE_CHECKING:
    from stable_baselines3.common.base_class import BaseAlgorithm

Layers = tuple[tuple[NDArray[np.float32], NDArray[np.float32]], ...]

POLICY_CLASSES = (("stable_baselines3.sac.policies", "SACPolicy"), ("sb3_contrib.tqc.policies", "TQCPolicy"))
"""(module, class) of the policies whose MlpPolicy actor is SAC's: a Linear-ReLU stack, a Linear mean, tanh."""

ACTOR_NEUTRAL_KWARGS = frozenset(
    {
        *("net_arch", "use_sde", "n_critics", "n_quantiles", "share_features_extractor", "optimizer_class"),
        *("optimizer_kwargs", "log_std_init", "use_expln", "clip_mean", "full_std"),
    }
)
"""``policy_kwargs`` that leave the deterministic actor without gSDE a Linear-ReLU stack (the sizes come from the
weights); any other (an activation, a features extractor) makes :func:`read_actor` decline the file."""

_STORAGE_DTYPES = {"FloatStorage": "<f4", "DoubleStorage": "<f8", "HalfStorage": "<f2"}


@dataclass(frozen=True)
class MlpActor:
    """A deterministic MLP actor: ReLU between its Linear layers, tanh after the last, unscaled to the action box.

    Attributes:
        layers: (weight ``(out, in)``, bias ``(out,)``) float32 pairs, input layer first.
        low: Lower bounds of the action space, float32 ``(3,)``.
        high: Upper bounds of the action space, float32 ``(3,)``.
    """

    layers: Layers
    low: NDArray[np.float32]
    high: NDArray[np.float32]

    def __call__(self, observation: NDArray[np.float32]) -> NDArray[np.float32]:
        """The action for one observation ``(N_in,)`` or a batch ``(N, N_in)``: SB3's ``unscale_action`` of the
        tanh of the mean, as ``predict(observation, deterministic=True)`` computes it, to float32 round-off."""
        hidden = np.asarray(observation, dtype=np.float32)
        last = len(self.layers) - 1
        for index, (weight, bias) in enumerate(self.layers):
            hidden = hidden @ weight.T + bias
            if index < last:
                np.maximum(hidden, 0.0, out=hidden)
        return self.low + (0.5 * (np.tanh(hidden) + 1.0) * (self.high - self.low))


def model_actor(model: BaseAlgorithm) -> MlpActor | None:
    """The actor of a loaded SAC (or TQC) model when it is a plain MLP (flattened input, Linear and ReLU layers, a
    Linear mean, no gSDE); None for any other actor (PPO, CrossQ, gSDE, other activations or feature extractors)."""
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
    layers = tuple(
        (m.weight.detach().numpy().astype(np.float32), m.bias.detach().numpy().astype(np.float32)) for m in linear
    )
    space = model.action_space
    return MlpActor(layers, np.asarray(space.low, np.float32), np.asarray(space.high, np.float32))


def read_actor(path: str | Path) -> MlpActor | None:
    """The actor of the SB3 zip at ``path``, read without SB3 or torch; None when it is not SAC's plain MLP
    (:data:`POLICY_CLASSES`, :data:`ACTOR_NEUTRAL_KWARGS`, no gSDE, only Linear weights in the actor, as many
    outputs as actions) or when its members are not in the form this reader knows (another torch serialization,
    dtype or byte order): SB3 then loads the file whole.

    Raises:
        ValueError: if ``path`` is not a zip; the message names the path.
    """
    try:
        with zipfile.ZipFile(path) as archive:
            try:
                data = json.loads(archive.read("data"))
                if not _is_plain_mlp_policy(data):
                    return None
                state = _state_dict(archive.read("policy.pth"))
                space = _SpaceUnpickler(io.BytesIO(base64.b64decode(data["action_space"][":serialized:"]))).load()
                low, high = np.asarray(space.low, "<f4"), np.asarray(space.high, "<f4")
            except Exception:  # a form this reader does not know; SB3 reads it or says what is wrong
                return None
    except zipfile.BadZipFile as error:
        raise ValueError(f"could not read the actor of {path}: {error}") from error
    layers = _mlp_layers(state)
    if layers is None or layers[-1][0].shape[0] != low.shape[0] or low.shape != high.shape:
        return None
    return MlpActor(layers, low, high)


def _is_plain_mlp_policy(data: dict[str, Any]) -> bool:
    """Whether SB3's ``data`` member describes a SAC-like MlpPolicy without gSDE and with default layers."""
    serialized = base64.b64decode(data["policy_class"][":serialized:"])
    names = tuple(arg for _, arg, _ in pickletools.genops(serialized) if isinstance(arg, str))
    kwargs = data.get("policy_kwargs", {})
    return names in POLICY_CLASSES and not data.get("use_sde", False) and set(kwargs) <= ACTOR_NEUTRAL_KWARGS


def _mlp_layers(state: dict[str, NDArray[Any]]) -> Layers | None:
    """The actor's Linear (weight, bias) pairs of ``latent_pi.0, .2, ...`` then ``mu``; None when the actor holds any
    other parameter (a normalization layer, a features extractor) or the shapes do not chain."""
    actor = {key.removeprefix("actor."): value for key, value in state.items() if key.startswith("actor.")}
    hidden = sorted({int(key.split(".")[1]) for key in actor if key.startswith("latent_pi.")})
    names = [f"latent_pi.{index}" for index in hidden] + ["mu"]
    expected = {f"{name}.{part}" for name in names for part in ("weight", "bias")}
    expected |= {"log_std.weight", "log_std.bias"} & set(actor)  # the stochastic policy's spread: not deployed
    if set(actor) != expected or hidden != list(range(0, 2 * len(hidden), 2)):
        return None
    if any(actor[f"{name}.weight"].ndim != 2 or actor[f"{name}.bias"].ndim != 1 for name in names):
        return None
    layers = tuple((actor[f"{name}.weight"], actor[f"{name}.bias"]) for name in names)
    for (weight, bias), (following, _) in itertools.pairwise(layers):
        if weight.shape[0] != bias.shape[0] or following.shape[1] != weight.shape[0]:
            return None
    return tuple((np.asarray(w, np.float32), np.asarray(b, np.float32)) for w, b in layers)


def _state_dict(serialized: bytes) -> dict[str, NDArray[Any]]:
    """The tensors of a ``torch.save``'d state dict (zip serialization, little-endian) as arrays."""
    with zipfile.ZipFile(io.BytesIO(serialized)) as archive:
        pickled = next(name for name in archive.namelist() if name.endswith("/data.pkl"))
        root = pickled.removesuffix("data.pkl")
        if archive.read(f"{root}byteorder") != b"little":
            raise ValueError("the tensors are not little-endian")
        return _TensorUnpickler(io.BytesIO(archive.read(pickled)), archive, root).load()


class _TensorUnpickler(pickle.Unpickler):
    """Unpickles a state dict: only an OrderedDict of tensors, each rebuilt as an array from its storage."""

    def __init__(self, file: io.BytesIO, archive: zipfile.ZipFile, root: str) -> None:
        super().__init__(file)
        self._archive, self._root = archive, root

    def find_class(self, module: str, name: str) -> Any:
        if (module, name) == ("collections", "OrderedDict"):
            return collections.OrderedDict
        if (module, name) == ("torch._utils", "_rebuild_tensor_v2"):
            return _rebuild_tensor
        if module == "torch" and name in _STORAGE_DTYPES:
            return np.dtype(_STORAGE_DTYPES[name])
        raise pickle.UnpicklingError(f"a policy state dict holds only tensors, not {module}.{name}")

    def persistent_load(self, pid: Any) -> NDArray[Any]:
        kind, dtype, key, _location, count = pid
        if kind != "storage" or not isinstance(dtype, np.dtype):
            raise pickle.UnpicklingError(f"unknown storage {pid!r}")
        return np.frombuffer(self._archive.read(f"{self._root}data/{key}"), dtype=dtype, count=count)


class _SpaceUnpickler(pickle.Unpickler):
    """Unpickles SB3's action space: only gymnasium's Box and the NumPy arrays, dtypes and random generator state it
    holds, so that a policy file cannot run other code."""

    ALLOWED = frozenset(
        {
            ("gymnasium.spaces.box", "Box"),
            ("numpy", "dtype"),
            ("numpy", "ndarray"),
            ("numpy._core.numeric", "_frombuffer"),
            ("numpy.core.numeric", "_frombuffer"),
            ("numpy._core.multiarray", "_reconstruct"),
            ("numpy.core.multiarray", "_reconstruct"),
        }
    )

    def find_class(self, module: str, name: str) -> Any:
        if (module, name) in self.ALLOWED or module.startswith("numpy.random."):
            return super().find_class(module, name)
        raise pickle.UnpicklingError(f"an action space holds no {module}.{name}")


def _rebuild_tensor(
    storage: NDArray[Any], offset: int, size: tuple[int, ...], stride: tuple[int, ...], *_: Any
) -> NDArray[Any]:
    """torch's ``_rebuild_tensor_v2``: the view of ``storage`` at element ``offset`` with ``size`` and ``stride``
    (elements), copied."""
    strides = tuple(step * storage.itemsize for step in stride)
    return np.lib.stride_tricks.as_strided(storage[offset:], shape=size, strides=strides).copy()
