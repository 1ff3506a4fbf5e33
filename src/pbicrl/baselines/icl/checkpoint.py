"""Checkpoints of an ICL run (``checkpoint.pt``: tensors and plain values only, read with
``torch.load(weights_only=True)``, so a file put into a run directory by someone else cannot run code) and its
JSON files, all written atomically."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

try:
    import torch
except ImportError as exc:  # pragma: no cover - exercised only without the extra
    raise ImportError('pbicrl.baselines.icl needs PyTorch: pip install "pbicrl[rl]"') from exc

from pbicrl._atomic import atomic_path, write_json
from pbicrl.baselines.session import load_safely

__all__ = ["CHECKPOINT", "write_json_file", "load_checkpoint", "save_checkpoint"]

CHECKPOINT = "checkpoint.pt"
"""File name of the resume point in a run directory."""


def write_json_file(path: Path, obj: Any) -> None:
    """Write ``obj`` as JSON atomically (NumPy values as lists, anything else JSON lacks as text)."""
    write_json(path, obj, default=lambda o: o.tolist() if hasattr(o, "tolist") else str(o))


def _plain_state(obj: Any) -> Any:
    """A copy of a checkpoint with NumPy values made plain (Python numbers, tensors), so that it loads with
    ``torch.load(weights_only=True)``, which refuses every global it does not know."""
    if isinstance(obj, dict):
        return {k: _plain_state(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_plain_state(v) for v in obj]
    if isinstance(obj, tuple):
        return tuple(_plain_state(v) for v in obj)
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return torch.as_tensor(obj)
    return obj


def _numpy_safe_globals() -> list[Any]:
    """NumPy scalar reconstruction, for checkpoints written before :func:`_plain_state` held NumPy numbers. These
    globals build dtypes and scalars from bytes; anything else a pickle might ask for stays refused."""
    out: list[Any] = [np.dtype]
    core = getattr(np, "_core", None) or getattr(np, "core", None)
    scalar = getattr(getattr(core, "multiarray", None), "scalar", None)
    if scalar is not None:
        out.append(scalar)
    dtypes = getattr(np, "dtypes", None)
    if dtypes is not None:
        for name in ("Float64DType", "Float32DType", "Int64DType", "Int32DType", "BoolDType"):
            if hasattr(dtypes, name):
                out.append(getattr(dtypes, name))
    return out


def load_checkpoint(path: Path) -> dict[str, Any]:
    """Read a checkpoint of :func:`run_icl` safely (:func:`pbicrl.baselines.session.load_safely`); errors name the
    file."""
    obj = load_safely(path, "out_dir", "it is not a checkpoint of this pbicrl version, or it is damaged. Delete it "
                                       "to start the run afresh", safe_globals=_numpy_safe_globals())
    if not isinstance(obj, dict) or "state" not in obj:
        raise ValueError(f"out_dir: {path} is not an ICL checkpoint (no 'state'); delete it to start afresh")
    return obj


def save_checkpoint(obj: Any, path: Path) -> None:
    """``torch.save`` of ``obj`` (NumPy values made plain, see :func:`_plain_state`) to ``path`` atomically."""
    with atomic_path(path) as tmp:
        torch.save(_plain_state(obj), tmp)
