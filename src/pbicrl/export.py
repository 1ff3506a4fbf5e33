"""Export a posterior to ArviZ (InferenceData with arviz 0.x, DataTree with arviz 1.x) and NetCDF.

Needs ``pip install "pbicrl[diag]"`` (ArviZ and h5netcdf), imported lazily.

Layout (dimension ``feature`` has the dataset's feature names as coordinates, ``param`` the parameter names
of parametric constraints):

================ ============================ ===========================================================
group            variable                     meaning
================ ============================ ===========================================================
posterior        ``indicator`` (feature)      :math:`c_j \\in \\{0, 1\\}`
posterior        ``penalty`` (feature)        effective penalty :math:`c_j w_{p,j}`
posterior        ``penalty_weight`` (feature) :math:`w_{p,j}` as stored by the sampler (latent when off in
                                              the ``paper`` sampler, 0 when off in ``pbicrl``)
posterior        ``parameter`` (param)        constraint parameters, when the run has them
log_likelihood   ``preferences``              total log-likelihood of all preferences (one value per draw)
sample_stats     ``lp``, ``log_prior``        log posterior (up to a constant), log prior
constant_data    ``map_indicator``,           the MAP state and the nominal weights
                 ``map_penalty``,
                 ``nominal_weight`` (feature)
================ ============================ ===========================================================
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from pbicrl.data import _umask
from pbicrl.diagnostics import INSTALL_HINT, _arviz_major, require_arviz

__all__ = ["to_arviz", "to_netcdf"]


def _groups(post: Any) -> tuple[dict[str, dict[str, np.ndarray]], dict[str, list], dict[str, list[str]], dict[str, Any]]:
    names = [str(n) for n in post.feature_names]
    c = np.asarray(post.indicators).astype(np.int8)
    wp = np.asarray(post.penalty_weights, dtype=np.float64)
    ll = np.asarray(post.log_likelihood, dtype=np.float64)
    lp = np.asarray(getattr(post, "log_prior", np.zeros_like(ll)), dtype=np.float64)
    posterior = {"indicator": c, "penalty": c * wp, "penalty_weight": wp}
    coords: dict[str, list] = {"feature": names}
    dims: dict[str, list[str]] = {k: ["feature"] for k in ("indicator", "penalty", "penalty_weight",
                                                          "map_indicator", "map_penalty", "nominal_weight")}
    params = getattr(post, "parameters", None)
    if params is not None and np.size(params):
        params = np.asarray(params, dtype=np.float64)
        if params.ndim == 2:
            params = params[:, :, None]
        pnames = list(getattr(post, "parameter_names", None) or [f"theta{k}" for k in range(params.shape[2])])
        posterior["parameter"] = params
        coords["param"] = [str(n) for n in pnames]
        dims["parameter"] = ["param"]
        dims["map_parameter"] = ["param"]
    settings = dict(getattr(post, "settings", {}) or {})
    d = len(names)
    nominal = np.asarray(settings.get("nominal_weights") or np.zeros(d), dtype=np.float64).reshape(-1)
    const = {"map_indicator": np.asarray(post.map_indicators).astype(np.int8),
             "map_penalty": np.asarray(post.map_indicators) * np.asarray(post.map_penalty_weights, dtype=np.float64),
             "nominal_weight": nominal if nominal.size == d else np.full(d, np.nan)}
    map_params = getattr(post, "map_parameters", None)
    if "parameter" in posterior and map_params is not None:
        const["map_parameter"] = np.asarray(map_params, dtype=np.float64).reshape(-1)
    groups = {
        "posterior": posterior,
        "log_likelihood": {"preferences": ll},
        "sample_stats": {"lp": ll + lp, "log_prior": lp},
        "constant_data": const,
    }
    attrs = {"inference_library": "pbicrl", "method": str(getattr(post, "method", "")),
             "seed": int(getattr(post, "seed", 0)), "settings_json": json.dumps(settings, default=_json_default)}
    try:
        from pbicrl import __version__

        attrs["inference_library_version"] = __version__
    except ImportError:  # pragma: no cover
        pass
    return groups, coords, dims, attrs


def _json_default(o: Any) -> Any:
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, np.generic):
        return o.item()
    return str(o)


def to_arviz(post: Any) -> Any:
    """ArviZ object of a posterior (see the module docstring for its variables).

    Parameters
    ----------
    post : Posterior or RunRecord

    Returns
    -------
    arviz.InferenceData (arviz < 1) or xarray.DataTree (arviz >= 1)
    """
    az = require_arviz()
    groups, coords, dims, attrs = _groups(post)
    if _arviz_major(az) >= 1:
        # arviz 1.x takes attributes per group ("/" = the root node)
        return az.from_dict(groups, coords=coords, dims=dims, attrs={"/": attrs, "posterior": attrs})
    return az.from_dict(posterior=groups["posterior"], log_likelihood=groups["log_likelihood"],
                        sample_stats=groups["sample_stats"], constant_data=groups["constant_data"],
                        coords=coords, dims=dims, attrs=attrs)


def to_netcdf(post: Any, path: str | os.PathLike[str], *, overwrite: bool = False) -> Path:
    """Write :func:`to_arviz` of ``post`` to a NetCDF file atomically (temp file, then rename).

    Raises
    ------
    FileExistsError
        If ``path`` exists and ``overwrite`` is false.
    ImportError
        If ArviZ or a NetCDF engine (h5netcdf) is missing; the message names the pip command.
    """
    out = Path(path)
    if out.exists() and not overwrite:
        raise FileExistsError(f"--netcdf: {out} already exists; choose another file or pass --overwrite")
    data = to_arviz(post)
    try:
        import h5netcdf  # noqa: F401
        import h5py  # noqa: F401  (h5netcdf's backend, not always pulled in by it)
    except ImportError as exc:
        raise ImportError(f"NetCDF export needs h5netcdf ({exc}): {INSTALL_HINT}") from exc
    out.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{out.name}.", suffix=".tmp", dir=out.parent)
    os.close(fd)
    try:
        data.to_netcdf(tmp, engine="h5netcdf")
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp creates 0600
        os.replace(tmp, out)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return out
