"""Attacks of issue 31: files a user opens never run code, ``--overwrite`` and every writer never lose what
pbicrl did not write (or an input), the labelling server and its child hold up, and results that are not
results are refused or flagged.

Each test fails on the code before the fix it guards (a pickle payload that ran, a file that was lost, a
traceback, a silent accept).
"""

from __future__ import annotations

import base64
import json
import os
import pickle
import zipfile
from pathlib import Path

import numpy as np
import pytest

from pbicrl.cli import main


class _Payload:
    """Unpickling this touches ``marker``: proof that a loader ran code from a file."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self):
        return (os.system, (f"touch {self.marker}",))


def _cli(capsys: pytest.CaptureFixture, argv: list[str]) -> tuple[int, str]:
    rc = main(argv)
    err = capsys.readouterr().err
    assert "Traceback" not in err, err
    return rc, err


def _evil_torch_file(path: Path, marker: Path) -> Path:
    """What SB3's ``policy.save`` writes (``torch.save`` of Python objects), with a payload inside."""
    torch = pytest.importorskip("torch")
    torch.save({"data": _Payload(marker), "state_dict": {}}, path)
    return path


def _evil_sb3_model_zip(path: Path, marker: Path) -> Path:
    """An SB3 model zip whose settings hold a cloudpickled payload (what ``SAC.load`` deserialises)."""
    blob = base64.b64encode(pickle.dumps(_Payload(marker))).decode()
    data = {"policy_class": {":type:": "<class 'abc.ABCMeta'>", ":serialized:": blob},
            "observation_space": {":type:": "x", ":serialized:": blob}}
    with zipfile.ZipFile(path, "w") as zf:
        zf.writestr("data", json.dumps(data))
        zf.writestr("_stable_baselines3_version", "2.9.2")
    return path


# --------------------------------------------------------------------------------- 1. code execution
@pytest.fixture
def rl():
    pytest.importorskip("torch")
    pytest.importorskip("stable_baselines3")
    pytest.importorskip("gymnasium")


def test_a_policy_with_a_pickle_payload_never_runs(rl, tmp_path, capsys):
    from pbicrl.demonstrators.sac import load_policy
    from pbicrl.demonstrators.sac_files import SACFileError

    marker = tmp_path / "pwned"
    for evil in (_evil_torch_file(tmp_path / "evil.zip", marker), _evil_sb3_model_zip(tmp_path / "m.zip", marker)):
        with pytest.raises(SACFileError, match="Stable-Baselines3/pickle file.*convert"):
            load_policy(evil)
        assert not marker.exists()
    # the command line: a clean one-line error naming the option's file, nothing run
    for flag in ("--good-policy", "--violating-policy"):
        rc, err = _cli(capsys, ["envs", "demos", "--env", "point_mass", flag, str(tmp_path / "evil.zip"),
                                "-n", "1", "--max-episodes", "2", "--out", str(tmp_path / "d.npz")])
        assert rc == 2 and "evil.zip" in err and "pickle" in err, err
        assert not marker.exists() and not (tmp_path / "d.npz").exists()


def test_a_crafted_checkpoint_or_warm_start_never_runs(rl, tmp_path, capsys):
    marker = tmp_path / "pwned"
    # an earlier pbicrl's checkpoint layout, both files crafted
    run = tmp_path / "run"
    (run / "checkpoint").mkdir(parents=True)
    _evil_sb3_model_zip(run / "checkpoint" / "model.zip", marker)
    (run / "checkpoint" / "replay_buffer.pkl").write_bytes(pickle.dumps(_Payload(marker)))
    (run / "checkpoint" / "state.json").write_text('{"num_timesteps": 10}')
    rc, err = _cli(capsys, ["envs", "train", "--env", "point_mass", "--reward", "nominal", "--steps", "100",
                            "--out", str(run), "--quiet"])
    assert rc == 2 and "pickle format" in err and "convert_sb3_checkpoint" in err, err
    assert not marker.exists()
    # the current layout with a crafted model.zip
    (run / "checkpoint" / "replay_buffer.pkl").unlink()
    np.savez(run / "checkpoint" / "replay_buffer.npz", x=np.zeros(1))
    rc, err = _cli(capsys, ["envs", "train", "--env", "point_mass", "--reward", "nominal", "--steps", "100",
                            "--out", str(run), "--quiet"])
    assert rc == 2 and "checkpoint" in err and "pickle" in err, err
    assert not marker.exists()
    # warm starts from a crafted file
    evil = _evil_torch_file(tmp_path / "evil.zip", marker)
    _evil_sb3_model_zip(run / "final_model.zip", marker)
    for argv in (["--init-from", str(evil)], ["--init-from", str(run / "final_model.zip")],
                 ["--relabel-from", str(run)]):
        rc, err = _cli(capsys, ["envs", "train", "--env", "point_mass", "--reward", "true", "--steps", "100",
                                "--out", str(tmp_path / "new"), "--quiet", *argv])
        assert rc == 2 and "pickle" in err and not marker.exists(), err
    # a replay buffer .npz holding pickled objects is refused by allow_pickle=False
    from pbicrl.demonstrators.sac_files import SACFileError, read_buffer_arrays

    np.save(tmp_path / "obj.npy", np.array([_Payload(marker)], dtype=object), allow_pickle=True)
    with zipfile.ZipFile(tmp_path / "buf.npz", "w") as zf:
        zf.write(tmp_path / "obj.npy", "observations.npy")
    with pytest.raises(SACFileError, match="replay buffer"):
        read_buffer_arrays(tmp_path / "buf.npz")
    assert not marker.exists()


def test_sac_files_refuse_settings_outside_the_schema(rl, tmp_path):
    """A pbicrl archive whose settings name anything outside the allow-lists is refused before any network is
    built; tensors-only weights are the only pickle read, with ``weights_only=True``."""
    import io

    import torch

    from pbicrl.demonstrators.sac_files import SACFileError, read_policy

    good = zipfile.ZipFile(Path(__file__).parents[1] / "src/pbicrl/data/policies/point_mass_good.zip")
    settings = json.loads(good.read("pbicrl.json"))
    weights = good.read("weights.pt")
    marker = tmp_path / "pwned"

    def archive(name: str, s: dict, w: bytes = weights) -> Path:
        p = tmp_path / name
        with zipfile.ZipFile(p, "w") as zf:
            zf.writestr("pbicrl.json", json.dumps(s))
            zf.writestr("weights.pt", w)
        return p

    bad_act = json.loads(json.dumps(settings))
    bad_act["policy"]["activation_fn"] = "os.system"
    with pytest.raises(SACFileError, match="activation_fn"):
        read_policy(archive("a.zip", bad_act))
    bad_fe = json.loads(json.dumps(settings))
    bad_fe["policy"]["features_extractor"] = {"class": "subprocess.Popen", "kwargs": {}}
    with pytest.raises(SACFileError, match="features_extractor"):
        read_policy(archive("b.zip", bad_fe))
    huge = json.loads(json.dumps(settings))
    huge["policy"]["net_arch"] = [10**9]
    with pytest.raises(SACFileError, match="net_arch"):
        read_policy(archive("c.zip", huge))
    buf = io.BytesIO()
    torch.save({"policy": _Payload(marker)}, buf)
    with pytest.raises(SACFileError, match="tensors-only"):
        read_policy(archive("d.zip", settings, buf.getvalue()))
    assert not marker.exists()
    (tmp_path / "e.zip").write_bytes(b"junk")
    with pytest.raises(SACFileError, match="not a zip"):
        read_policy(tmp_path / "e.zip")


def test_shipped_policies_are_in_the_safe_format_and_act(rl):
    from pbicrl.cli.navigation import DATA_DIR
    from pbicrl.demonstrators.sac import load_policy
    from pbicrl.demonstrators.sac_files import is_sb3_file

    files = sorted((DATA_DIR / "policies").glob("*.zip"))
    assert len(files) == 8
    for f in files:
        assert not is_sb3_file(f)
        assert "pbicrl.json" in zipfile.ZipFile(f).namelist()
    pol = load_policy(DATA_DIR / "policies" / "point_mass_good.zip")
    a, _ = pol.predict(np.array([0.0, 0.0], dtype=np.float32), deterministic=True)
    assert a.shape == (2,) and np.all(np.abs(a) <= 1.0)


def test_a_feature_file_runs_only_after_the_dataset_is_found(tmp_path, capsys):
    pytest.importorskip("minari")
    marker = tmp_path / "ran"
    feats = tmp_path / "f.py"
    feats.write_text(f"open({str(marker)!r}, 'w').close()\ndef f(ep):\n    return [[0.0]]\n")
    (tmp_path / "root").mkdir()
    rc, err = _cli(capsys, ["import", "minari", "nope/nothing-v0", "--features", f"{feats}:f", "--root",
                            str(tmp_path / "root"), "--out", str(tmp_path / "o.npz")])
    assert rc == 2 and "nope/nothing-v0" in err, err
    assert not marker.exists(), "the feature file ran before the dataset was looked up"
