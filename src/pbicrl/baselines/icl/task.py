"""ICL as a task kind (``reproduce-icl``): one seed on a dataset's good demonstrations, resumable through a
checkpoint directory that outlives the task's temporary output."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from pbicrl.baselines.icl.environments import expert_coordinates, point_mass_expert_demos
from pbicrl.baselines.icl.presets import ENVS, ICLConfig, icl_preset
from pbicrl.baselines.icl.run import run_icl

__all__ = ["run_icl_task"]


def run_icl_task(config: dict, out_dir: Path) -> dict[str, Any]:
    """Task entry point (``"pbicrl.baselines.icl:run_icl_task"``, defined here): one ICL seed on a dataset's good demos.

    Config keys: ``env`` (``halfcheetah``/``ant``/``point_mass``), ``data`` (path to a
    :class:`pbicrl.inference.data.Dataset` with states; or ``"scripted"`` for the point mass's scripted expert),
    ``budget`` (preset name) and/or ``icl`` (dict of :class:`ICLConfig` overrides), ``budget_sha256`` (ignored
    here: lets a caller hash the preset's values into the task), ``seed``, ``n_expert``
    (default 200), ``expert_group`` (default 1), ``demos_seed`` (the draw of the expert demonstrations),
    ``checkpoint_dir`` (a directory that outlives the task's temporary output directory so an interrupted task
    resumes; default: inside ``out_dir``, i.e. no resume). The old names ``dataset`` and ``sample_seed`` are
    accepted until pbicrl 0.3 with a :class:`~pbicrl.errors.PbicrlWarning`.
    """
    from pbicrl.config import ConfigError

    config = dict(config)
    for old, new in (("dataset", "data"), ("sample_seed", "demos_seed")):
        if old in config:
            if new in config:
                raise ConfigError(f"{old}: deprecated name of '{new}', which is given too; keep only '{new}'")
            from pbicrl.errors import warn

            warn(f"ICL task key '{old}' is deprecated and will be removed in pbicrl 0.3: use '{new}'")
            config[new] = config.pop(old)
    env = config.get("env")
    if env not in ENVS:
        raise ValueError(f"env: expected one of {ENVS}, got {env!r}")
    budget = config.get("budget", "default")
    cfg = icl_preset(budget, env)
    if config.get("icl"):
        base = cfg.to_dict()
        over = dict(config["icl"])
        if "ppo" in over:
            base["ppo"] = {**base["ppo"], **over.pop("ppo")}
        base.update(over)
        cfg = ICLConfig.from_dict(base)
    seed = int(config.get("seed", 0))
    data = config.get("data")
    if data == "scripted":
        if env != "point_mass":
            raise ValueError("data: 'scripted' exists only for env point_mass")
        expert = point_mass_expert_demos(int(config.get("n_expert", 200) or 200), seed=int(config.get("demos_seed", 0)))
    elif data:
        expert = expert_coordinates(data, group=int(config.get("expert_group", 1)),
                                    n=config.get("n_expert", 200), seed=int(config.get("demos_seed", 0)))
    else:
        raise ValueError("data: required (path of a dataset with states, or 'scripted' for point_mass)")
    run_dir = Path(config["checkpoint_dir"]) if config.get("checkpoint_dir") else Path(out_dir) / "icl"
    summary = run_icl(env, expert, cfg, run_dir, seed=seed, progress=bool(config.get("progress", False)))
    if run_dir != Path(out_dir) / "icl":
        import shutil

        (Path(out_dir) / "icl").mkdir(parents=True, exist_ok=True)
        for name in ("summary.json", "budget.json", "progress.log", "constraint.pt", "constraint_grid.npz"):
            if (run_dir / name).exists():
                shutil.copy2(run_dir / name, Path(out_dir) / "icl" / name)
    return {k: summary[k] for k in ("env", "seed", "n_expert", "location", "cmse_location", "cmse_grid", "runtime_s",
                                    "ppo_steps", "lambda", "final_policy", "sessions")} | {"budget": budget,
                                                                                          "total_ppo_steps": cfg.total_steps,
                                                                                          "rounds": cfg.rounds}
