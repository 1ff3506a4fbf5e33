"""Attacks of issue 31: files a user opens never run code, ``--overwrite`` and every writer never lose what
pbicrl did not write (or an input), the labelling server and its child hold up, and results that are not
results are refused or flagged.

Each test fails on the code before the fix it guards (a pickle payload that ran, a file that was lost, a
traceback, a silent accept).
"""

from __future__ import annotations

import base64
import errno
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


@pytest.mark.parametrize("state, message", [("{bad", "not readable JSON"), ("[1]", "JSON object"),
                                            ('{"num_timesteps": "x"}', "'num_timesteps'")])
def test_a_malformed_checkpoint_state_names_the_file(rl, tmp_path, capsys, state, message):
    run = tmp_path / "run"
    (run / "checkpoint").mkdir(parents=True)
    (run / "checkpoint" / "model.zip").write_bytes(b"junk")
    np.savez(run / "checkpoint" / "replay_buffer.npz", x=np.zeros(1))
    (run / "checkpoint" / "state.json").write_text(state)
    rc, err = _cli(capsys, ["envs", "train", "--env", "point_mass", "--reward", "nominal", "--steps", "100",
                            "--out", str(run), "--quiet"])
    assert rc == 2 and "state.json" in err and message in err, err


def test_a_malformed_policy_file_is_a_clean_error_on_the_command_line(rl, tmp_path, capsys):
    good = zipfile.ZipFile(Path(__file__).parents[1] / "src/pbicrl/data/policies/point_mass_good.zip")
    junk, cut, bad_json, bad_weights = (tmp_path / n for n in ("junk.zip", "cut.zip", "json.zip", "weights.zip"))
    junk.write_bytes(b"junk")
    cut.write_bytes((Path(__file__).parents[1] / "src/pbicrl/data/policies/point_mass_good.zip").read_bytes()[:50_000])
    for path, settings, weights in ((bad_json, "{not json", b"x"), (bad_weights, good.read("pbicrl.json"), b"x" * 64)):
        with zipfile.ZipFile(path, "w") as zf:
            zf.writestr("pbicrl.json", settings)
            zf.writestr("weights.pt", weights)
    for path, message in ((junk, "not a zip"), (cut, "not a zip"), (bad_json, "not valid JSON"),
                          (bad_weights, "tensors-only")):
        rc, err = _cli(capsys, ["envs", "demos", "--env", "point_mass", "--good-policy", str(path), "-n", "1",
                                "--max-episodes", "2", "--out", str(tmp_path / "d.npz")])
        assert rc == 2 and path.name in err and message in err and "weights_only=False" not in err, err
        assert not (tmp_path / "d.npz").exists()


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


# --------------------------------------------------------------------------------- 2-4. data loss
@pytest.fixture(scope="module")
def demo_npz(tmp_path_factory) -> Path:
    from pbicrl.inference.synthetic import make_problem

    p = tmp_path_factory.mktemp("demo") / "demo.npz"
    make_problem(8, labels="violations", violation_rate=0.4, seed=3).dataset.save(p)
    return p


def _digest(d: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in d.iterdir() if p.is_file()}


QUICK = ["--iterations", "300", "--chains", "1", "--no-progress"]


def test_overwrite_replaces_only_a_run_pbicrl_wrote_and_never_an_input(demo_npz, tmp_path, capsys):
    run = tmp_path / "runA"
    assert main(["infer", str(demo_npz), "--out", str(run), *QUICK]) == 0
    capsys.readouterr()
    assert main(["infer", str(demo_npz), "--out", str(run), "--overwrite", *QUICK]) == 0  # its own output: fine
    capsys.readouterr()
    # the labelling page's layout: the dataset inside the run it is inferred into
    (run / "data.npz").write_bytes(demo_npz.read_bytes())
    before = _digest(run)
    rc, err = _cli(capsys, ["infer", str(run / "data.npz"), "--out", str(run), "--overwrite", *QUICK])
    assert rc == 2 and "input" in err and "data.npz" in err, err
    assert _digest(run) == before
    # a --config inside the output
    (run / "cfg.toml").write_text("iterations = 300\nchains = 1\n")
    rc, err = _cli(capsys, ["infer", str(demo_npz), "--config", str(run / "cfg.toml"), "--out", str(run),
                            "--overwrite", "--no-progress"])
    assert rc == 2 and "cfg.toml" in err, err
    rc, err = _cli(capsys, ["tune-margins", str(run / "data.npz"), "--relation", "1", "--out", str(run),
                            "--overwrite", "--iterations", "200", "--no-progress"])
    assert rc == 2 and "input" in err, err
    assert (run / "data.npz").read_bytes() == demo_npz.read_bytes() and (run / "cfg.toml").is_file()
    # a run directory with a file pbicrl did not write (legacy, no marker, and with a marker)
    legacy = tmp_path / "legacy"
    legacy.mkdir()
    for name in ("summary.json", "chains.npz"):
        (legacy / name).write_bytes((run / name).read_bytes())
    (legacy / "thesis.tex").write_text("\\chapter{}")
    (run / "notes.txt").write_text("mine")
    for target, extra in ((legacy, "thesis.tex"), (run, "notes.txt")):
        rc, err = _cli(capsys, ["infer", str(demo_npz), "--out", str(target), "--overwrite", *QUICK])
        assert rc == 2 and extra in err and "did not write" in err, err
        assert (target / extra).is_file()
    # a directory of another kind (what train-safe writes) is not a run
    safe = tmp_path / "safe"
    safe.mkdir()
    for name in ("policy.pt", "checkpoint.pt", "budget.json", "summary.json"):
        (safe / name).write_text("x")
    rc, err = _cli(capsys, ["infer", str(demo_npz), "--out", str(safe), "--overwrite", *QUICK])
    assert rc == 2 and sorted(p.name for p in safe.iterdir()) == ["budget.json", "checkpoint.pt", "policy.pt",
                                                                  "summary.json"], err


def test_figures_written_into_a_run_stay_replaceable_with_it(demo_npz, tmp_path, capsys):
    pytest.importorskip("matplotlib")
    run = tmp_path / "run"
    assert main(["infer", str(demo_npz), "--out", str(run), *QUICK]) == 0
    assert main(["plot", str(run)]) == 0
    rc, err = _cli(capsys, ["plot", str(run)])  # the figures exist now: replaced only with --overwrite
    assert rc == 2 and "trace.png" in err and "--overwrite" in err, err
    assert main(["plot", str(run), "--overwrite"]) == 0
    assert main(["infer", str(demo_npz), "--out", str(run), "--overwrite", *QUICK]) == 0
    assert not (run / "plots").exists()
    other = tmp_path / "figs"
    other.mkdir()
    (other / "trace.png").write_bytes(b"my own figure")
    rc, err = _cli(capsys, ["plot", str(run), "--out", str(other)])
    assert rc == 2 and (other / "trace.png").read_bytes() == b"my own figure", err


def test_export_never_overwrites_the_runs_dataset(demo_npz, tmp_path, capsys):
    pytest.importorskip("arviz")
    run = tmp_path / "run"
    data = tmp_path / "data.npz"
    data.write_bytes(demo_npz.read_bytes())
    assert main(["infer", str(data), "--out", str(run), *QUICK]) == 0
    capsys.readouterr()
    for argv in (["--netcdf", str(data), "--overwrite"], ["--netcdf", str(data), "--data", str(data), "--overwrite"]):
        rc, err = _cli(capsys, ["export", str(run), *argv])
        assert rc == 2 and "input" in err, err
    assert data.read_bytes() == demo_npz.read_bytes()


def test_label_export_never_replaces_its_pool_or_another_file_unasked(demo_npz, tmp_path, capsys):
    from pbicrl.inference.data import load_dataset

    pool = tmp_path / "pool.npz"
    pool.write_bytes(demo_npz.read_bytes())
    for argv in ([], ["--overwrite"]):
        rc, err = _cli(capsys, ["label", str(pool), "--export", str(pool), *argv])
        assert rc == 2 and "input" in err, err
    assert pool.read_bytes() == demo_npz.read_bytes()
    notes = tmp_path / "notes.npz"
    notes.write_text("my notes")
    rc, err = _cli(capsys, ["label", str(pool), "--export", str(notes)])
    assert rc == 2 and "--overwrite" in err and notes.read_text() == "my notes", err
    assert main(["label", str(pool), "--export", str(notes), "--overwrite"]) == 0
    assert load_dataset(notes).n_trajectories > 0


def test_envs_writers_replace_a_file_only_with_overwrite(tmp_path, capsys):
    pytest.importorskip("gymnasium")
    out = tmp_path / "grid.npz"
    out.write_text("precious")
    rc, err = _cli(capsys, ["envs", "grid", "--out", str(out)])
    assert rc == 2 and "--overwrite" in err and out.read_text() == "precious", err
    assert main(["envs", "grid", "--out", str(out), "--overwrite"]) == 0
    report = tmp_path / "d.json"
    report.write_text("precious")
    rc, err = _cli(capsys, ["envs", "demos", "--env", "point_mass", "-n", "1", "--max-episodes", "1",
                            "--out", str(tmp_path / "d.npz")])
    assert rc == 2 and "d.json" in err and report.read_text() == "precious", err
    rc, err = _cli(capsys, ["envs", "minari-to-npz", "--id", "x/y-v0", "--out", str(out)])
    assert rc == 2 and "--overwrite" in err, err
    pol = tmp_path / "p.zip"
    pol.write_text("policy")
    rc, err = _cli(capsys, ["envs", "demos-wall", "--env", "ant", "--good-policy", str(pol), "--violating-policy",
                            str(pol), "--out", str(pol), "--overwrite"])
    assert rc == 2 and pol.read_text() == "policy", err


def test_demos_wall_never_writes_over_a_real_policy_and_a_short_run_is_a_clean_error(rl, tmp_path, capsys):
    """The replay of session 15: with a real policy (a text file is refused as 'not a zip archive' before any output
    check) the --report may not be an input; and a run whose rollouts cannot fill a group ended in a RuntimeError
    traceback, now a one-line error naming --max-attempts-factor."""
    pytest.importorskip("mujoco")
    import hashlib
    import shutil

    from pbicrl.inference.data import shipped_dir

    good, bad = tmp_path / "good.zip", tmp_path / "bad.zip"
    shutil.copy(shipped_dir() / "policies" / "ant_good.zip", good)
    shutil.copy(shipped_dir() / "policies" / "ant_violating.zip", bad)
    digest = hashlib.sha256(good.read_bytes()).hexdigest()
    rc, err = _cli(capsys, ["envs", "demos-wall", "--env", "ant", "--good-policy", str(good), "--violating-policy",
                            str(bad), "--out", str(tmp_path / "w"), "--report", str(good), "--overwrite"])
    assert rc == 2 and "--report" in err and hashlib.sha256(good.read_bytes()).hexdigest() == digest, err
    rc, err = _cli(capsys, ["envs", "demos-wall", "--env", "ant", "--good-policy", str(good), "--violating-policy",
                            str(bad), "--out", str(tmp_path / "w"), "-n", "1", "--steps", "20",
                            "--max-attempts-factor", "2"])
    assert rc == 2 and "acceptable rollouts" in err and "--max-attempts-factor" in err, err
    assert not (tmp_path / "w.npz").exists()


# --------------------------------------------------------------------------------- 5-6. labelling server
@pytest.fixture
def label_client(tmp_path):
    pytest.importorskip("starlette")
    pytest.importorskip("httpx")
    from starlette.testclient import TestClient

    from pbicrl.inference.data import Dataset
    from pbicrl.ui.server import create_app
    from pbicrl.ui.session import LabelSession

    rng = np.random.default_rng(0)
    trajs = [rng.normal(size=(5, 2)) for _ in range(6)]
    pool = tmp_path / "pool.npz"
    Dataset.from_trajectories(trajs, np.zeros(6, dtype=int), states=[t.copy() for t in trajs],
                              allow_unlabelled=True).save(pool)
    session = LabelSession(pool, tmp_path / "labelled.npz")
    with TestClient(create_app(session), base_url="http://127.0.0.1") as c:
        yield c, session


def _post(client, path: str, body: bytes | str, **headers: str):
    return client.post(path, content=body, headers={"Content-Type": "application/json", **headers})


def test_label_server_refuses_deep_huge_and_foreign_requests_with_4xx(label_client, tmp_path):
    client, session = label_client
    rev = session.revision
    r = _post(client, "/api/assign", "[" * 50_000 + "]" * 50_000)
    assert r.status_code == 400 and "nested" in r.json()["error"], r.text
    r = _post(client, "/api/assign", '{"revision": %d, "ids": [0], "group": 1, "x": %s}' % (rev, "[" * 40 + "]" * 40))
    assert r.status_code == 400 and "nested" in r.json()["error"], r.text
    for path, body in (("/api/gaps", '{"revision": %d, "gap_relation": [%d]}' % (rev, 10**30)),
                       ("/api/infer", '{"margins": [%d]}' % 10**30),
                       ("/api/assign", '{"revision": %d, "ids": [0], "group": %d}' % (rev, 2**64))):
        r = _post(client, path, body)
        assert r.status_code == 400 and "out of range" in r.json()["error"], (path, r.text)
    r = _post(client, "/api/gaps", '{"revision": %d, "gap_relation": [NaN]}' % rev)
    assert r.status_code == 400, r.text
    # a chunked body (no Content-Length) is counted while it streams in
    from pbicrl.ui.server import MAX_BODY_BYTES

    def chunks():
        for _ in range(MAX_BODY_BYTES // 65536 + 2):
            yield b" " * 65536

    r = client.post("/api/assign", content=chunks(), headers={"Content-Type": "application/json"})
    assert r.status_code == 413, r.text
    # a page elsewhere (Origin) or the test client's default host
    r = _post(client, "/api/assign", '{"revision": %d, "ids": [0], "group": 1}' % rev, Origin="http://evil.example")
    assert r.status_code == 403 and "origin" in r.json()["error"], r.text
    assert client.get("/api/state", headers={"host": "testserver"}).status_code == 400
    assert session.revision == rev and not (tmp_path / "labelled.npz").exists()
    r = _post(client, "/api/assign", '{"revision": %d, "ids": [0], "group": 1}' % rev, Origin="http://127.0.0.1")
    assert r.status_code == 200, r.text


def test_label_on_a_public_address_needs_an_allow_list(tmp_path, capsys):
    pytest.importorskip("starlette")
    from pbicrl.ui.server import create_app
    from pbicrl.ui.session import LabelSession

    pool = tmp_path / "p.npz"
    from pbicrl.inference.data import Dataset

    Dataset.from_trajectories([np.zeros((2, 1))] * 2, [0, 0], states=[np.zeros((2, 1))] * 2,
                              allow_unlabelled=True).save(pool)
    rc, err = _cli(capsys, ["label", str(pool), "--out", str(tmp_path / "o.npz"), "--host", "0.0.0.0",
                            "--no-browser"])
    assert rc == 2 and "--allow-host" in err, err
    session = LabelSession(pool, tmp_path / "o.npz")
    with pytest.raises(ValueError, match="allow_host"):
        create_app(session, host="0.0.0.0")
    from starlette.testclient import TestClient

    with TestClient(create_app(session, host="0.0.0.0", allow_hosts=["lab.example"]),
                    base_url="http://lab.example") as c:
        assert c.get("/api/state").status_code == 200
        assert c.get("/api/state", headers={"host": "evil.example"}).status_code == 400
        assert c.get("/api/state", headers={"host": "127.0.0.1"}).status_code == 400


@pytest.mark.skipif(not os.path.exists("/proc"), reason="/proc")
def test_the_inference_child_of_label_dies_with_its_parent(tmp_path):
    """SIGKILL of the labelling server (here: a process holding an InferenceJob) ends the inference child
    and leaves no snapshot folder."""
    import signal
    import subprocess
    import sys
    import textwrap
    import time

    from pbicrl.inference.synthetic import make_problem

    data = tmp_path / "d.npz"
    make_problem(8, labels="violations", seed=1).dataset.save(data)
    snap_dir = Path(__import__("tempfile").mkdtemp(prefix="pbicrl-label-999999999-"))  # a killed server's
    code = textwrap.dedent(f"""
        import os, shutil, sys, tempfile, time
        from pathlib import Path
        from pbicrl.ui.inference import InferenceJob, InferenceSettings
        snap = Path(tempfile.mkdtemp(prefix=f"pbicrl-label-{{os.getpid()}}-")) / "labelling.npz"
        shutil.copy({str(data)!r}, snap)
        job = InferenceJob()
        job.start(snap, Path({str(tmp_path / 'x.run')!r}), InferenceSettings(iterations=10**8, chains=1,
                  figures=False), 0)
        print(job._proc.pid, snap.parent, flush=True)
        while job.snapshot()["phase"] in ("starting", "preparing"):
            time.sleep(0.2)
        print("sampling", flush=True)
        time.sleep(600)
    """)
    import pbicrl

    env = {**os.environ, "PYTHONPATH": str(Path(pbicrl.__file__).parents[1])}
    parent = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True, env=env)
    try:
        child_pid, snap = parent.stdout.readline().split()
        assert parent.stdout.readline().strip() == "sampling"
        child_pid = int(child_pid)
        assert Path(f"/proc/{child_pid}").exists()
    finally:
        parent.kill()
        parent.wait()
    deadline = time.time() + 20
    while time.time() < deadline and Path(f"/proc/{child_pid}").exists():
        status = Path(f"/proc/{child_pid}/stat").read_text() if Path(f"/proc/{child_pid}/stat").exists() else ""
        if status and status[status.rindex(")") + 2] in "ZX":
            break
        time.sleep(0.2)
    alive = Path(f"/proc/{child_pid}/stat").exists() and Path(f"/proc/{child_pid}/stat").read_text().split(")")[-1].split()[0] not in "ZX"
    if alive:
        os.kill(child_pid, signal.SIGKILL)
    assert not alive, "the inference child outlived the killed server"
    assert not Path(snap).exists()  # the child removed the snapshot it had read
    from pbicrl.ui.server import _clean_stale_snapshots

    _clean_stale_snapshots()
    assert not snap_dir.exists()  # a dead server's folder is removed by the next one


# --------------------------------------------------------------------------------- 7. results that are not results
def test_nan_chains_are_refused_by_every_reader(demo_npz, tmp_path, capsys):
    run = tmp_path / "run"
    assert main(["infer", str(demo_npz), "--out", str(run), *QUICK]) == 0
    capsys.readouterr()
    with np.load(run / "chains.npz") as z:
        arrays = {k: z[k] for k in z.files}
    arrays["penalty_weights"] = np.full_like(arrays["penalty_weights"], np.nan)
    np.savez(run / "chains.npz", **arrays)
    commands = [["diagnose", str(run)], ["check", str(run), "--data", str(demo_npz)],
                ["suggest", str(run), "--pool", str(demo_npz)], ["export", str(run), "--netcdf", str(tmp_path / "p.nc")],
                ["plot", str(run), "--out", str(tmp_path / "figs")]]
    for argv in commands:
        rc, err = _cli(capsys, argv)
        assert rc == 2 and "penalty_weights" in err and "NaN" in err, (argv, err)
    assert not (tmp_path / "p.nc").exists() and not (tmp_path / "figs").exists()


@pytest.mark.parametrize("argv, needle", [
    (["--beta", "1e308"], "beta"), (["--beta", "1e-300"], "beta"), (["--margins", "0,1e308"], "out of range"),
    (["--thin", "1000000000"], "draw"), (["--iterations", "1"], "draw"),
])
def test_settings_that_give_no_posterior_are_refused_up_front(demo_npz, tmp_path, capsys, argv, needle):
    args = ["--iterations", "300", "--chains", "1", "--no-progress", *argv]
    rc, err = _cli(capsys, ["infer", str(demo_npz), "--out", str(tmp_path / "r"), *args])
    assert rc == 2 and needle in err, err
    assert not (tmp_path / "r").exists()


def test_identify_refuses_a_beta_that_overflows(capsys):
    rc, err = _cli(capsys, ["identify", "point_mass", "--beta", "1e308"])
    assert rc == 2 and "beta" in err, err


def test_an_infer_whose_draws_are_nan_exits_non_zero_and_writes_nothing(demo_npz, tmp_path, capsys, monkeypatch):
    import pbicrl.api as api

    real = api.infer_from_config

    def nan_draws(*a, **k):
        post = real(*a, **k)
        post.penalty_weights[...] = np.nan
        return post

    monkeypatch.setattr(api, "infer_from_config", nan_draws)
    rc, err = _cli(capsys, ["infer", str(demo_npz), "--out", str(tmp_path / "r"), *QUICK])
    assert rc == 2 and "no usable draws" in err and not (tmp_path / "r").exists(), err


# --------------------------------------------------------------------------------- 8. sweep size
def test_a_sweep_grid_is_sized_before_it_is_expanded(tmp_path, capsys):
    import resource
    import subprocess
    import sys

    grid = "\n".join(f"k{i} = [{', '.join(str(v) for v in range(60))}]" for i in range(8))
    cfg = tmp_path / "explode.toml"
    cfg.write_text(f'[base]\nkind = "infer"\ndata = "example"\n[grid]\n{grid}\n')

    def limit() -> None:
        resource.setrlimit(resource.RLIMIT_AS, (1 << 30, 1 << 30))

    proc = subprocess.run([sys.executable, "-m", "pbicrl.cli", "sweep", str(cfg), "--dry-run"], capture_output=True,
                          text=True, timeout=120, preexec_fn=limit)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr and "MemoryError" not in proc.stderr, proc.stderr
    assert "167,961,600,000,000 runs" in proc.stderr, proc.stderr


# --------------------------------------------------------------------------------- 10. tracebacks and silent ignores
def test_a_path_longer_than_the_os_allows_is_a_clean_error(tmp_path, capsys):
    long = str(tmp_path / ("a" * 300 + ".npz"))
    for argv in (["info", long], ["identify", long], ["infer", long, "--out", str(tmp_path / "o")]):
        rc, err = _cli(capsys, argv)
        assert rc == 2 and "cannot be looked up" in err, (argv, err)


def test_reproduce_checks_its_data_overrides_before_running(demo_npz, tmp_path, capsys):
    rc, err = _cli(capsys, ["reproduce", "point-mass", "--data", f"nope={demo_npz}", "--out", str(tmp_path / "r")])
    assert rc == 2 and "nope" in err, err
    # a file whose layout the experiments cannot index (3 features where point_mass has 4); names may differ
    # (stand-ins and relabelled copies are fine: tests/experiments/test_reproduce.py)
    from pbicrl.inference.data import Dataset, load_dataset

    ds = load_dataset(demo_npz)
    narrow = tmp_path / "narrow.npz"
    Dataset(features=ds.features[:, :3], offsets=ds.offsets, group=ds.group).save(narrow)
    rc, err = _cli(capsys, ["reproduce", "point-mass", "--data", f"point_mass={narrow}", "--out",
                            str(tmp_path / "r")])
    assert rc == 2 and "point_mass" in err and "features" in err, err
    assert not (tmp_path / "r" / "runs").exists()


def test_tune_margins_with_an_empty_grid_is_an_error(demo_npz, tmp_path, capsys):
    rc, err = _cli(capsys, ["tune-margins", str(demo_npz), "--relation", "1,1", "--grid", "", "--out",
                            str(tmp_path / "t")])
    assert rc == 2 and "--grid" in err, err


@pytest.mark.parametrize("where, err", [("lock", errno.EACCES), ("temporary", errno.EACCES), ("temporary", errno.EROFS)])
def test_an_unwritable_out_directory_is_named_not_the_lock_or_temporary(demo_npz, tmp_path, capsys, monkeypatch, where,
                                                                        err):
    # root writes anywhere, so the read-only parent is simulated: creating pbicrl's claim (.<name>.lock) or its
    # temporary (.<name>.tmp-...) there fails as it would on a read-only directory or file system
    ro = tmp_path / "ro"
    ro.mkdir()
    real_open, real_mkdir = os.open, os.mkdir

    def refuse(path: object) -> None:
        p = Path(os.fsdecode(path))
        if p.parent == ro and (p.name.endswith(".lock") if where == "lock" else ".tmp-" in p.name):
            raise OSError(err, os.strerror(err), os.fsdecode(path)) if err == errno.EROFS else \
                PermissionError(err, os.strerror(err), os.fsdecode(path))

    monkeypatch.setattr(os, "open", lambda path, *a, **k: (refuse(path), real_open(path, *a, **k))[1])
    monkeypatch.setattr(os, "mkdir", lambda path, *a, **k: (refuse(path), real_mkdir(path, *a, **k))[1])
    for argv in (["infer", str(demo_npz), *QUICK], ["tune-margins", str(demo_npz), "--relation", "1,1", "--grid", "0,1"]):
        rc, msg = _cli(capsys, [*argv, "--out", str(ro / "run")])
        assert rc == 2 and f"out: cannot write {ro / 'run'}: " in msg, (argv, msg)
        assert os.strerror(err).lower() in msg and ".lock" not in msg and ".tmp-" not in msg, msg
        assert not (ro / "run").exists()


def test_malformed_constraint_values_name_the_constraint(demo_npz, tmp_path, capsys):
    cfg = tmp_path / "c.toml"
    cfg.write_text('[[constraints]]\nfamily = "ball"\nname = "disc"\ndims = [0, 1]\nbounds = [["x", 1], [0, 1], [0, 1]]\n')
    rc, err = _cli(capsys, ["infer", str(demo_npz), "--config", str(cfg), "--out", str(tmp_path / "o"), *QUICK])
    assert rc == 2 and "disc" in err and "bounds" in err, err


# --------------------------------------------------------------------------------- 9. identify with many features
def _many_features(d: int, n: int = 90, length: int = 4, seed: int = 0):
    from pbicrl.inference.data import Dataset

    rng = np.random.default_rng(seed)
    return Dataset(features=rng.random((n * length, d)), offsets=np.arange(n + 1) * length,
                   group=np.repeat([1, 2, 3], n // 3), feature_names=tuple(f"f{j}" for j in range(d)),
                   nominal_weights=np.zeros(d))


def test_identify_needs_a_few_lps_not_one_per_feature_when_no_penalty_is_unbounded():
    pytest.importorskip("scipy")
    from pbicrl.analysis.identify import identify

    res = identify(_many_features(60))
    assert not res.separable and not any(f.unbounded for f in res.features)
    assert res.n_lp <= 4, res.n_lp  # one recession LP per feature before: 61


def test_identify_shows_progress_when_it_runs_long(monkeypatch, capsys):
    pytest.importorskip("scipy")
    import pbicrl.analysis.identify as ident

    monkeypatch.setattr(ident, "_PROGRESS_DELAY_S", 0.0)
    ident.identify(_many_features(8), progress=True)
    assert "identify:" in capsys.readouterr().err
    ident.identify(_many_features(8))
    assert "identify:" not in capsys.readouterr().err
