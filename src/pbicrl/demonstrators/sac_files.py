"""SAC policies, models and replay buffers on disk in a form that cannot run code when read.

Stable-Baselines3 saves policies with ``torch.save`` of Python objects (read back with
``torch.load(weights_only=False)``), models as zips whose settings are cloudpickled, and replay buffers with
``pickle``: opening such a file runs whatever code it was made to hold. pbicrl writes and reads its own format
instead:

* a **policy file** (``policy.zip``, the shipped ``<env>_<role>.zip``) is a zip archive with two members:
  ``pbicrl.json``, the settings that rebuild the networks (spaces, layer sizes, activation and feature
  extractor, each checked against a fixed schema and allow-list), and ``weights.pt``, the ``state_dict``
  read with ``torch.load(weights_only=True)`` (tensors only);
* a **model file** (``final_model.zip``, ``checkpoint/model.zip``) adds the SAC hyperparameters and step
  counters to the settings and the optimiser states and entropy coefficient to the weights;
* a **replay buffer** is an ``.npz`` of plain arrays read with ``allow_pickle=False``.

A Stable-Baselines3 file is refused with a message saying how to convert one the user trusts
(:func:`convert_sb3_file`, :func:`convert_sb3_checkpoint`: the only functions here that run a pickle, on
purpose, and only when called by name).

Torch and Stable-Baselines3 are imported lazily (extra ``rl``).
"""

from __future__ import annotations

import io
import json
import math
import os
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from pbicrl._atomic import atomic_path

__all__ = ["SACFileError", "POLICY_FORMAT", "MODEL_FORMAT", "save_policy", "read_policy", "save_model",
           "read_model", "save_replay_buffer", "read_replay_buffer", "is_sb3_file", "convert_sb3_file",
           "convert_sb3_checkpoint", "file_format", "read_buffer_arrays"]

POLICY_FORMAT = "pbicrl-sac-policy"
MODEL_FORMAT = "pbicrl-sac-model"
_VERSION = 1
_SETTINGS = "pbicrl.json"
_WEIGHTS = "weights.pt"
#: Caps that keep a crafted file from asking for unbounded memory before anything is checked.
_MAX_SETTINGS_BYTES = 1 << 20
_MAX_WEIGHTS_BYTES = 4 << 30
_MAX_DIM = 1 << 20
_MAX_LAYERS = 16
_MAX_UNITS = 1 << 16
_ACTIVATIONS = ("ReLU", "Tanh", "ELU", "LeakyReLU", "GELU", "SiLU")
_EXTRACTORS = ("FlattenExtractor", "AffineObservation", "RBFObservation")
_BUFFER_FIELDS = ("observations", "next_observations", "actions", "rewards", "dones", "timeouts")


class SACFileError(ValueError):
    """A policy, model or replay-buffer file that pbicrl does not read; the message names the file and why."""


def _sb3_advice(path: Path) -> str:
    return (f"{path} is a Stable-Baselines3/pickle file, and reading one can run code stored in it, so pbicrl "
            "reads only its own weights-and-settings format; convert a file you trust with "
            "pbicrl.demonstrators.sac_files.convert_sb3_file (or convert_sb3_checkpoint for a run directory)")


# ------------------------------------------------------------------------------------------------- settings
def _space_to_json(space: Any, what: str) -> dict[str, Any]:
    from gymnasium import spaces

    if not isinstance(space, spaces.Box):
        raise SACFileError(f"{what}: only Box spaces can be saved, got {type(space).__name__}")
    return {"shape": [int(s) for s in space.shape], "dtype": str(np.dtype(space.dtype)),
            "low": np.asarray(space.low, dtype=np.float64).reshape(-1).tolist(),
            "high": np.asarray(space.high, dtype=np.float64).reshape(-1).tolist()}


def _require(cond: bool, where: str, msg: str) -> None:
    if not cond:
        raise SACFileError(f"{where}: {msg}")


def _is_num(x: Any) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool)


def _space_from_json(obj: Any, where: str) -> Any:
    from gymnasium import spaces

    _require(isinstance(obj, dict) and set(obj) == {"shape", "dtype", "low", "high"}, where,
             "must be an object with exactly shape, dtype, low, high")
    shape = obj["shape"]
    _require(isinstance(shape, list) and 1 <= len(shape) <= 4
             and all(isinstance(s, int) and not isinstance(s, bool) and s >= 1 for s in shape), f"{where}.shape",
             "must be a list of 1-4 positive integers")
    n = math.prod(shape)
    _require(n <= _MAX_DIM, f"{where}.shape", f"too large ({n} values)")
    _require(obj["dtype"] in ("float32", "float64"), f"{where}.dtype", "must be float32 or float64")
    bounds = []
    for key in ("low", "high"):
        v = obj[key]
        _require(isinstance(v, list) and len(v) == n and all(_is_num(x) and not math.isnan(x) for x in v),
                 f"{where}.{key}", f"must be a list of {n} numbers")
        bounds.append(np.asarray(v, dtype=np.float64).reshape(shape).astype(obj["dtype"]))
    _require(bool(np.all(bounds[0] <= bounds[1])), where, "low must not exceed high")
    return spaces.Box(low=bounds[0], high=bounds[1], shape=tuple(shape), dtype=np.dtype(obj["dtype"]))


def _net_arch_ok(v: Any) -> bool:
    def layers(x: Any) -> bool:
        return (isinstance(x, list) and len(x) <= _MAX_LAYERS
                and all(isinstance(h, int) and not isinstance(h, bool) and 1 <= h <= _MAX_UNITS for h in x))

    if isinstance(v, dict):
        return set(v) == {"pi", "qf"} and layers(v["pi"]) and layers(v["qf"])
    return layers(v)


def _plain(value: Any) -> Any:
    """Tuples to lists, numpy scalars to Python: what JSON keeps."""
    if isinstance(value, (list, tuple, np.ndarray)):
        return [_plain(v) for v in value]
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, np.generic):
        return value.item()
    return value


def _policy_settings(params: dict[str, Any]) -> dict[str, Any]:
    """JSON settings from SB3's ``policy._get_constructor_parameters()``; refuses anything outside the schema."""
    import torch

    act = params.get("activation_fn")
    fe = params.get("features_extractor_class")
    opt = params.get("optimizer_class", torch.optim.Adam)
    if getattr(act, "__name__", None) not in _ACTIVATIONS or act is not getattr(torch.nn, act.__name__):
        raise SACFileError(f"activation_fn: {act!r} is not one of {_ACTIVATIONS}")
    if getattr(fe, "__name__", None) not in _EXTRACTORS:
        raise SACFileError(f"features_extractor_class: {fe!r} is not one of {_EXTRACTORS}")
    if opt is not torch.optim.Adam:
        raise SACFileError(f"optimizer_class: only Adam can be saved, got {opt!r}")
    out = {
        "observation_space": _space_to_json(params["observation_space"], "observation_space"),
        "action_space": _space_to_json(params["action_space"], "action_space"),
        "net_arch": _plain(params.get("net_arch") or [256, 256]),
        "activation_fn": act.__name__,
        "use_sde": bool(params.get("use_sde", False)), "log_std_init": float(params.get("log_std_init", -3.0)),
        "use_expln": bool(params.get("use_expln", False)), "clip_mean": float(params.get("clip_mean", 2.0)),
        "n_critics": int(params.get("n_critics", 2)), "normalize_images": bool(params.get("normalize_images", True)),
        "share_features_extractor": bool(params.get("share_features_extractor", False)),
        "features_extractor": {"class": fe.__name__, "kwargs": _plain(params.get("features_extractor_kwargs") or {})},
        "optimizer_kwargs": _plain(params.get("optimizer_kwargs") or {}),
    }
    _check_policy_settings(json.loads(json.dumps(out)), "settings")
    return out


def _check_kwargs(obj: Any, where: str, allowed: dict[str, str]) -> None:
    _require(isinstance(obj, dict) and set(obj) <= set(allowed), where,
             f"must be an object with keys among {sorted(allowed)}")
    for k, kind in allowed.items():
        if k not in obj:
            continue
        v = obj[k]
        if kind == "number":
            _require(_is_num(v) and math.isfinite(v), f"{where}.{k}", "must be a finite number")
        elif kind == "int":
            _require(isinstance(v, int) and not isinstance(v, bool) and 1 <= v <= 64, f"{where}.{k}",
                     "must be an integer in 1..64")
        elif kind == "numbers":
            _require(isinstance(v, list) and 1 <= len(v) <= _MAX_DIM
                     and all(_is_num(x) and math.isfinite(x) for x in v), f"{where}.{k}",
                     "must be a list of finite numbers")
        elif kind == "pair":
            _require(isinstance(v, list) and len(v) == 2 and all(_is_num(x) and math.isfinite(x) for x in v),
                     f"{where}.{k}", "must be two finite numbers")
        elif kind == "bool":
            _require(isinstance(v, bool), f"{where}.{k}", "must be true or false")


def _check_policy_settings(s: Any, where: str) -> None:
    keys = {"observation_space", "action_space", "net_arch", "activation_fn", "use_sde", "log_std_init",
            "use_expln", "clip_mean", "n_critics", "normalize_images", "share_features_extractor",
            "features_extractor", "optimizer_kwargs"}
    _require(isinstance(s, dict) and set(s) == keys, where, f"must be an object with exactly the keys {sorted(keys)}")
    _require(_net_arch_ok(s["net_arch"]), f"{where}.net_arch",
             f"must be a list of at most {_MAX_LAYERS} layer sizes in 1..{_MAX_UNITS} (or pi/qf lists)")
    _require(s["activation_fn"] in _ACTIVATIONS, f"{where}.activation_fn", f"must be one of {_ACTIVATIONS}")
    for k in ("use_sde", "use_expln", "normalize_images", "share_features_extractor"):
        _require(isinstance(s[k], bool), f"{where}.{k}", "must be true or false")
    for k in ("log_std_init", "clip_mean"):
        _require(_is_num(s[k]) and math.isfinite(s[k]), f"{where}.{k}", "must be a finite number")
    _require(isinstance(s["n_critics"], int) and not isinstance(s["n_critics"], bool) and 1 <= s["n_critics"] <= 16,
             f"{where}.n_critics", "must be an integer in 1..16")
    fe = s["features_extractor"]
    _require(isinstance(fe, dict) and set(fe) == {"class", "kwargs"} and fe["class"] in _EXTRACTORS,
             f"{where}.features_extractor", f"must be {{class, kwargs}} with class one of {_EXTRACTORS}")
    allowed = {"FlattenExtractor": {}, "AffineObservation": {"low": "numbers", "high": "numbers"},
               "RBFObservation": {"low": "numbers", "high": "numbers", "n_per_dim": "int"}}[fe["class"]]
    _check_kwargs(fe["kwargs"], f"{where}.features_extractor.kwargs", allowed)
    _check_kwargs(s["optimizer_kwargs"], f"{where}.optimizer_kwargs",
                  {"eps": "number", "weight_decay": "number", "betas": "pair", "amsgrad": "bool"})


def _policy_kwargs(s: dict[str, Any]) -> dict[str, Any]:
    """SB3 ``policy_kwargs`` (classes looked up in the allow-lists) from checked settings."""
    import torch
    from stable_baselines3.common.torch_layers import FlattenExtractor

    from pbicrl.demonstrators import _extractors

    fe_cls = {"FlattenExtractor": FlattenExtractor, "AffineObservation": _extractors.AffineObservation,
              "RBFObservation": _extractors.RBFObservation}[s["features_extractor"]["class"]]
    opt_kwargs = dict(s["optimizer_kwargs"])
    if "betas" in opt_kwargs:
        opt_kwargs["betas"] = tuple(opt_kwargs["betas"])
    return {"net_arch": s["net_arch"], "activation_fn": getattr(torch.nn, s["activation_fn"]),
            "use_sde": s["use_sde"], "log_std_init": s["log_std_init"], "use_expln": s["use_expln"],
            "clip_mean": s["clip_mean"], "n_critics": s["n_critics"], "normalize_images": s["normalize_images"],
            "share_features_extractor": s["share_features_extractor"], "features_extractor_class": fe_cls,
            "features_extractor_kwargs": dict(s["features_extractor"]["kwargs"]),
            "optimizer_class": torch.optim.Adam, "optimizer_kwargs": opt_kwargs}


# -------------------------------------------------------------------------------------------------- archive
def is_sb3_file(path: str | os.PathLike[str]) -> bool:
    """Whether ``path`` looks like a Stable-Baselines3 model zip or a ``torch.save`` pickle (not pbicrl's format)."""
    try:
        with zipfile.ZipFile(path) as zf:
            names = zf.namelist()
    except (zipfile.BadZipFile, OSError):
        return False
    return _SETTINGS not in names and ("data" in names or any(n.endswith("/data.pkl") for n in names))


def _write_archive(path: Path, settings: dict[str, Any], weights: dict[str, Any]) -> None:
    import torch

    buf = io.BytesIO()
    torch.save(weights, buf)
    with atomic_path(path) as tmp:
        with zipfile.ZipFile(tmp, "w", compression=zipfile.ZIP_STORED) as zf:
            zf.writestr(_SETTINGS, json.dumps(settings, indent=1, sort_keys=True))
            zf.writestr(_WEIGHTS, buf.getvalue())


def _read_archive(path: Path, fmt: str, what: str) -> tuple[dict[str, Any], dict[str, Any]]:
    """Settings (JSON, version checked) and weights (``weights_only=True``) of a pbicrl archive."""
    import pickle

    import torch

    if not path.is_file():
        raise FileNotFoundError(f"{what}: no such file {path}")
    try:
        with zipfile.ZipFile(path) as zf:
            names = zf.namelist()
            if _SETTINGS not in names or _WEIGHTS not in names:
                if "data" in names or any(n.endswith("/data.pkl") for n in names):
                    raise SACFileError(f"{what}: {_sb3_advice(path)}")
                raise SACFileError(f"{what}: {path} is not a pbicrl SAC file (no {_SETTINGS} and {_WEIGHTS})")
            info_s, info_w = zf.getinfo(_SETTINGS), zf.getinfo(_WEIGHTS)
            if info_s.file_size > _MAX_SETTINGS_BYTES or info_w.file_size > _MAX_WEIGHTS_BYTES:
                raise SACFileError(f"{what}: {path}: a member is larger than a SAC file can be")
            raw_settings = zf.read(_SETTINGS)
            raw_weights = zf.read(_WEIGHTS)
    except zipfile.BadZipFile:
        raise SACFileError(f"{what}: {path} is not a zip archive (a pbicrl SAC file is one)") from None
    except OSError as exc:
        raise SACFileError(f"{what}: cannot read {path} ({exc.strerror or exc})") from None
    try:
        settings = json.loads(raw_settings.decode("utf-8"))
    except (UnicodeDecodeError, ValueError, RecursionError) as exc:
        raise SACFileError(f"{what}: {path}: {_SETTINGS} is not valid JSON ({exc})") from None
    _require(isinstance(settings, dict), f"{what}: {path}", f"{_SETTINGS} must hold an object")
    if settings.get("format") != fmt:
        raise SACFileError(f"{what}: {path} holds format {settings.get('format')!r}, expected {fmt!r}")
    if settings.get("version") != _VERSION:
        raise SACFileError(f"{what}: {path}: version {settings.get('version')!r} is not readable "
                           f"(this pbicrl reads version {_VERSION})")
    try:
        weights = torch.load(io.BytesIO(raw_weights), weights_only=True, map_location="cpu")
    except (pickle.UnpicklingError, RuntimeError, EOFError, ValueError, TypeError, AttributeError) as exc:
        # torch's own message goes on to advise weights_only=False, which is what must not be done with such a file
        raise SACFileError(f"{what}: {path}: {_WEIGHTS} is not a tensors-only file (damaged, or it holds Python "
                           "objects, which pbicrl never unpickles)") from None
    _require(isinstance(weights, dict), f"{what}: {path}", f"{_WEIGHTS} must hold a dict")
    return settings, weights


def _state_dict(obj: Any, where: str) -> dict[str, Any]:
    import torch

    _require(isinstance(obj, dict) and all(isinstance(k, str) and isinstance(v, torch.Tensor) for k, v in obj.items()),
             where, "must map parameter names to tensors")
    return obj


# -------------------------------------------------------------------------------------------------- policies
def save_policy(policy: Any, path: str | os.PathLike[str]) -> Path:
    """Write an SB3 ``SACPolicy`` as a pbicrl policy file (atomically); return the path."""
    path = Path(path)
    settings = {"format": POLICY_FORMAT, "version": _VERSION,
                "policy": _policy_settings(policy._get_constructor_parameters())}
    _write_archive(path, settings, {"policy": {k: v.detach().cpu() for k, v in policy.state_dict().items()}})
    return path


def _build_policy(s: dict[str, Any], where: str, device: str) -> Any:
    from stable_baselines3.sac.policies import SACPolicy

    _check_policy_settings(s, where)
    obs = _space_from_json(s["observation_space"], f"{where}.observation_space")
    act = _space_from_json(s["action_space"], f"{where}.action_space")
    try:
        policy = SACPolicy(obs, act, lambda _: 0.0, **_policy_kwargs(s))
    except (ValueError, TypeError, RuntimeError) as exc:
        raise SACFileError(f"{where}: these settings do not build a SAC policy ({exc})") from None
    return policy.to(device)


def _load_state(module: Any, sd: dict[str, Any], where: str) -> None:
    import torch

    try:
        if isinstance(module, torch.optim.Optimizer):
            module.load_state_dict(sd)
        else:
            module.load_state_dict(sd, strict=True)
    except (RuntimeError, KeyError, ValueError, TypeError, IndexError) as exc:
        raise SACFileError(f"{where}: the weights do not fit the settings ({str(exc).splitlines()[0]})") from None


def read_policy(path: str | os.PathLike[str], device: str = "cpu", *, what: str = "policy") -> Any:
    """Read a pbicrl policy file, or the policy of a pbicrl model file; return an SB3 ``SACPolicy`` in eval mode.

    Raises
    ------
    FileNotFoundError
        No such file.
    SACFileError
        A Stable-Baselines3/pickle file (refused: reading it could run code), or a file that is not valid.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{what}: no such file {path}")
    fmt = MODEL_FORMAT if file_format(path) == MODEL_FORMAT else POLICY_FORMAT
    settings, weights = _read_archive(path, fmt, what)
    where = f"{what}: {path}"
    policy = _build_policy(settings.get("policy"), f"{where}: policy", device)
    _load_state(policy, _state_dict(weights.get("policy"), f"{where}: weights.policy"), where)
    policy.set_training_mode(False)
    return policy


def file_format(path: str | os.PathLike[str]) -> Any:
    """The ``format`` a pbicrl SAC file declares (``None`` for anything else); reads only its settings."""
    try:
        with zipfile.ZipFile(path) as zf:
            if zf.getinfo(_SETTINGS).file_size > _MAX_SETTINGS_BYTES:
                return None
            return json.loads(zf.read(_SETTINGS).decode("utf-8")).get("format")
    except (zipfile.BadZipFile, OSError, KeyError, ValueError, UnicodeDecodeError, AttributeError, RecursionError):
        return None


# ---------------------------------------------------------------------------------------------------- models
_SAC_KEYS = {"learning_rate": "number", "buffer_size": "count", "learning_starts": "count0", "batch_size": "count",
             "tau": "number", "gamma": "number", "train_freq": "count", "train_freq_unit": "unit",
             "gradient_steps": "int", "target_update_interval": "count", "ent_coef": "ent",
             "target_entropy": "number", "handle_timeout_termination": "bool", "num_timesteps": "count0",
             "episode_num": "count0", "n_updates": "count0"}


def _check_sac_settings(s: Any, where: str) -> None:
    _require(isinstance(s, dict) and set(s) == set(_SAC_KEYS), where,
             f"must be an object with exactly the keys {sorted(_SAC_KEYS)}")
    for k, kind in _SAC_KEYS.items():
        v, w = s[k], f"{where}.{k}"
        is_int = isinstance(v, int) and not isinstance(v, bool)
        if kind == "number":
            _require(_is_num(v) and math.isfinite(v), w, "must be a finite number")
        elif kind == "count":
            _require(is_int and 1 <= v <= 10**12, w, "must be a positive integer")
        elif kind == "count0":
            _require(is_int and 0 <= v <= 10**15, w, "must be a non-negative integer")
        elif kind == "int":
            _require(is_int and -1 <= v <= 10**6 and v != 0, w, "must be -1 or a positive integer")
        elif kind == "unit":
            _require(v in ("step", "episode"), w, "must be 'step' or 'episode'")
        elif kind == "bool":
            _require(isinstance(v, bool), w, "must be true or false")
        elif kind == "ent":
            ok = (_is_num(v) and math.isfinite(v) and v >= 0) or (isinstance(v, str) and (
                v == "auto" or (v.startswith("auto_") and _finite_text(v[5:]))))
            _require(ok, w, "must be 'auto', 'auto_<number>' or a non-negative number")
    _require(s["buffer_size"] <= 10**8, f"{where}.buffer_size", "must be at most 1e8")


def _finite_text(text: str) -> bool:
    try:
        return math.isfinite(float(text))
    except ValueError:
        return False


def save_model(model: Any, path: str | os.PathLike[str]) -> Path:
    """Write an SB3 ``SAC`` model (networks, optimisers, entropy coefficient, counters) as a pbicrl model file."""
    lr = model.learning_rate
    if not _is_num(lr):
        raise SACFileError(f"learning_rate: only a constant learning rate can be saved, got {lr!r}")
    sac = {"learning_rate": float(lr), "buffer_size": int(model.buffer_size),
           "learning_starts": int(model.learning_starts), "batch_size": int(model.batch_size),
           "tau": float(model.tau), "gamma": float(model.gamma), "train_freq": int(model.train_freq.frequency),
           "train_freq_unit": str(model.train_freq.unit.value), "gradient_steps": int(model.gradient_steps),
           "target_update_interval": int(model.target_update_interval),
           "ent_coef": model.ent_coef if isinstance(model.ent_coef, str) else float(model.ent_coef),
           "target_entropy": float(model.target_entropy),
           "handle_timeout_termination": bool(getattr(model.replay_buffer, "handle_timeout_termination", True)),
           "num_timesteps": int(model.num_timesteps), "episode_num": int(model._episode_num),
           "n_updates": int(getattr(model, "_n_updates", 0))}
    settings = {"format": MODEL_FORMAT, "version": _VERSION,
                "policy": _policy_settings(model.policy._get_constructor_parameters()), "sac": sac}
    _check_sac_settings(json.loads(json.dumps(sac)), "sac")
    weights: dict[str, Any] = {"policy": {k: v.detach().cpu() for k, v in model.policy.state_dict().items()},
                               "actor.optimizer": model.actor.optimizer.state_dict(),
                               "critic.optimizer": model.critic.optimizer.state_dict()}
    if getattr(model, "ent_coef_optimizer", None) is not None:
        weights["ent_coef_optimizer"] = model.ent_coef_optimizer.state_dict()
        weights["log_ent_coef"] = model.log_ent_coef.detach().cpu()
    _write_archive(Path(path), settings, weights)
    return Path(path)


def read_model(path: str | os.PathLike[str], env: Any, *, device: str = "cpu", what: str = "model",
               overrides: dict[str, Any] | None = None) -> Any:
    """Rebuild an SB3 ``SAC`` model on ``env`` from a pbicrl model file.

    ``overrides`` replaces hyperparameters (``learning_rate``, ``batch_size``, ``buffer_size``,
    ``learning_starts``, ``gamma``, ``tau``, ``train_freq``, ``gradient_steps``, ``target_entropy``) for a
    warm start; the networks, optimiser states and entropy coefficient come from the file. The replay buffer
    is empty (see :func:`read_replay_buffer`).
    """
    import torch
    from stable_baselines3 import SAC

    path = Path(path)
    settings, weights = _read_archive(path, MODEL_FORMAT, what)
    where = f"{what}: {path}"
    ps = settings.get("policy")
    _check_policy_settings(ps, f"{where}: policy")
    s = settings.get("sac")
    _check_sac_settings(s, f"{where}: sac")
    obs = _space_from_json(ps["observation_space"], f"{where}: policy.observation_space")
    act = _space_from_json(ps["action_space"], f"{where}: policy.action_space")
    if env is not None:
        for name, space, mine in (("observation", env.observation_space, obs), ("action", env.action_space, act)):
            if tuple(space.shape) != tuple(mine.shape):
                raise SACFileError(f"{where}: saved for {name} shape {mine.shape}, the environment has {space.shape}")
    hyper = {k: s[k] for k in ("learning_rate", "buffer_size", "learning_starts", "batch_size", "tau", "gamma",
                               "gradient_steps", "target_entropy")}
    for k, v in (overrides or {}).items():
        if k not in hyper and k != "train_freq":
            raise ValueError(f"overrides: unknown hyperparameter {k!r}")
    hyper.update({k: v for k, v in (overrides or {}).items() if k != "train_freq"})
    train_freq = (overrides or {}).get("train_freq", (s["train_freq"], s["train_freq_unit"]))
    try:
        model = SAC("MlpPolicy", env, ent_coef=s["ent_coef"], train_freq=train_freq,
                    target_update_interval=s["target_update_interval"],
                    replay_buffer_kwargs={"handle_timeout_termination": s["handle_timeout_termination"]},
                    policy_kwargs=_policy_kwargs(ps), device=device, verbose=0, **hyper)
    except (ValueError, TypeError, RuntimeError) as exc:
        raise SACFileError(f"{where}: these settings do not build a SAC model ({exc})") from None
    _load_state(model.policy, _state_dict(weights.get("policy"), f"{where}: weights.policy"), where)
    for name, opt in (("actor.optimizer", model.actor.optimizer), ("critic.optimizer", model.critic.optimizer)):
        _require(isinstance(weights.get(name), dict), where, f"weights.{name} is missing")
        _load_state(opt, weights[name], f"{where}: weights.{name}")
    if model.ent_coef_optimizer is not None:
        log_ent = weights.get("log_ent_coef")
        _require(isinstance(log_ent, torch.Tensor) and tuple(log_ent.shape) == tuple(model.log_ent_coef.shape)
                 and isinstance(weights.get("ent_coef_optimizer"), dict), where,
                 "weights.log_ent_coef and weights.ent_coef_optimizer must match an automatic entropy coefficient")
        with torch.no_grad():
            model.log_ent_coef.copy_(log_ent)
        _load_state(model.ent_coef_optimizer, weights["ent_coef_optimizer"], f"{where}: weights.ent_coef_optimizer")
    model.num_timesteps = s["num_timesteps"]
    model._episode_num = s["episode_num"]
    model._n_updates = s["n_updates"]
    return model


# -------------------------------------------------------------------------------------------- replay buffers
def save_replay_buffer(model: Any, path: str | os.PathLike[str]) -> Path:
    """Write ``model.replay_buffer`` (an SB3 ``ReplayBuffer``) as an ``.npz`` of plain arrays (atomically)."""
    buf = model.replay_buffer
    n = buf.buffer_size if buf.full else buf.pos
    arrays = {k: np.asarray(getattr(buf, k))[:n] for k in _BUFFER_FIELDS}
    arrays["pos"] = np.array(buf.pos, dtype=np.int64)
    arrays["full"] = np.array(bool(buf.full))
    with atomic_path(Path(path)) as tmp:
        with open(tmp, "wb") as fh:
            np.savez(fh, **arrays)
    return Path(path)


def read_buffer_arrays(path: str | os.PathLike[str], what: str = "replay buffer") -> dict[str, np.ndarray]:
    """The arrays of a replay-buffer ``.npz`` (no pickles), checked for consistent lengths."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{what}: no such file {path}")
    try:
        with np.load(path, allow_pickle=False) as z:
            missing = [k for k in (*_BUFFER_FIELDS, "pos", "full") if k not in z.files]
            if missing:
                raise SACFileError(f"{what}: {path} lacks {', '.join(missing)}")
            out = {k: z[k] for k in (*_BUFFER_FIELDS, "pos", "full")}
    except ValueError as exc:  # a pickled array: refused by allow_pickle=False
        raise SACFileError(f"{what}: {path} is not a replay buffer of plain arrays ({exc})") from None
    except (OSError, zipfile.BadZipFile, EOFError) as exc:
        raise SACFileError(f"{what}: {path} is not a readable .npz ({exc})") from None
    n = out["observations"].shape[0] if out["observations"].ndim else -1
    if n < 0 or any(out[k].ndim < 2 or out[k].shape[0] != n for k in _BUFFER_FIELDS):
        raise SACFileError(f"{what}: {path}: the arrays must share their first length")
    if out["pos"].shape != () or out["full"].shape != () or not (0 <= int(out["pos"]) <= max(n, 0)):
        raise SACFileError(f"{what}: {path}: pos/full are not scalars consistent with {n} stored transitions")
    return out


def read_replay_buffer(model: Any, path: str | os.PathLike[str], what: str = "replay buffer") -> None:
    """Fill ``model.replay_buffer`` from an ``.npz`` written by :func:`save_replay_buffer`."""
    arrays = read_buffer_arrays(path, what)
    buf = model.replay_buffer
    n = arrays["observations"].shape[0]
    full = bool(arrays["full"])
    if n > buf.buffer_size or (full and n != buf.buffer_size) or (not full and int(arrays["pos"]) != n):
        raise SACFileError(f"{what}: {path}: {n} transitions (full={full}) do not fit a buffer of {buf.buffer_size}")
    for k in _BUFFER_FIELDS:
        dest = getattr(buf, k)
        if arrays[k].shape[1:] != dest.shape[1:]:
            raise SACFileError(f"{what}: {path}: {k} has shape {arrays[k].shape[1:]} per step, "
                               f"the model needs {dest.shape[1:]}")
        dest[:n] = arrays[k]
    buf.pos = int(arrays["pos"]) % buf.buffer_size
    buf.full = full


# ------------------------------------------------------------------------------------------------ conversion
def convert_sb3_file(src: str | os.PathLike[str], dst: str | os.PathLike[str]) -> Path:
    """Convert a Stable-Baselines3 policy (``policy.save``) or model zip (``model.save``) into pbicrl's format.

    **This runs the pickle in** ``src``: call it only on a file you trust (one you trained yourself). It is
    never called by pbicrl's commands; it exists to carry existing runs and policies over, once.
    """
    try:
        from stable_baselines3.sac.policies import SACPolicy
    except ImportError as exc:
        raise ImportError(f"converting a Stable-Baselines3 file needs it ({exc}): pip install \"pbicrl[rl]\"") from exc
    src = Path(src)
    with zipfile.ZipFile(src) as zf:
        whole_model = "data" in zf.namelist()
    if whole_model:
        from stable_baselines3 import SAC

        return save_model(SAC.load(src, device="cpu"), dst)
    return save_policy(SACPolicy.load(str(src), device="cpu"), dst)


def convert_sb3_checkpoint(run_dir: str | os.PathLike[str]) -> list[Path]:
    """Convert a run directory written by an earlier pbicrl (``final_model.zip``, ``policy.zip``,
    ``checkpoint/model.zip`` and ``checkpoint/replay_buffer.pkl`` as Stable-Baselines3 pickles) in place.

    **This runs the pickles in** ``run_dir``: call it only on a run you trust. Returns the files written.
    """
    from stable_baselines3 import SAC

    run = Path(run_dir)
    written = []
    for name in ("policy.zip", "final_model.zip", "checkpoint/model.zip", "checkpoint.old/model.zip"):
        p = run / name
        if p.is_file() and is_sb3_file(p):
            written.append(convert_sb3_file(p, p))
    for ck in ("checkpoint", "checkpoint.old"):
        pkl = run / ck / "replay_buffer.pkl"
        if pkl.is_file():
            from stable_baselines3.common.save_util import load_from_pkl

            model = SAC.__new__(SAC)  # a carrier for save_replay_buffer: only .replay_buffer is read
            model.replay_buffer = load_from_pkl(pkl)
            written.append(save_replay_buffer(model, pkl.with_suffix(".npz")))
            pkl.unlink()
    return written
