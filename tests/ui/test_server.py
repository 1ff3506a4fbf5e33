"""The labelling server's API through Starlette's test client (no browser)."""

from __future__ import annotations

import dataclasses
import os
import re
import time
import warnings

import numpy as np
import pytest

pytest.importorskip("starlette", reason='the labelling server needs the ui extra: pip install "pbicrl[ui]"')
pytest.importorskip("httpx", reason="Starlette's test client needs httpx")

import pbicrl  # noqa: E402
from pbicrl.cli import main  # noqa: E402
from pbicrl.inference.data import Dataset, DatasetError, load_dataset  # noqa: E402
from pbicrl.io.runs import read_run  # noqa: E402
from pbicrl.ui.server import create_app  # noqa: E402
from pbicrl.ui.session import LabelSession  # noqa: E402

with warnings.catch_warnings():
    warnings.simplefilter("ignore")  # Starlette's note about httpx2
    from starlette.testclient import TestClient  # noqa: E402

BASE = "http://127.0.0.1"


def make_pool(path, n: int = 30, env_id: str | None = "point_mass") -> tuple[str, np.ndarray]:
    """Every 40th point-mass demonstration, labels removed; returns the file and the true groups."""
    pm = pbicrl.load_dataset("point_mass")
    sub = pm.subset(np.arange(0, pm.n_trajectories, pm.n_trajectories // n)[:n])
    pool = dataclasses.replace(sub, group=np.zeros(sub.n_trajectories, dtype=np.int64), group_names=(),
                               allow_unlabelled=True, env_id=env_id)
    return str(pool.save(path)), sub.group.copy()


@pytest.fixture()
def pool(tmp_path):
    return make_pool(tmp_path / "pool.npz")


@pytest.fixture()
def client(pool, tmp_path):
    session = LabelSession(pool[0], tmp_path / "labelled.npz")
    with TestClient(create_app(session), base_url=BASE) as c:
        yield c


def test_load_page_state_scene_and_demos(client):
    page = client.get("/")
    assert page.status_code == 200 and "pbicrl label" in page.text
    assert client.get("/static/app.js").status_code == 200
    assert client.get("/static/nope.js").status_code == 404
    st = client.get("/api/state").json()
    assert st["revision"] == 1 and st["n"] == 30 and st["n_unlabelled"] == 30 and st["saved_revision"] == 0
    assert [g["name"] for g in st["groups"]] == ["good", "bad", "very bad"] and st["env_id"] == "point_mass"
    scene = client.get("/api/scene").json()
    assert scene["kind"] == "navigation"
    assert {r["name"] for r in scene["regions"]} == {"orange", "red", "goal"}
    thumbs = client.get("/api/thumbnails").json()["series"]
    assert len(thumbs) == 30 and len(thumbs[0][0]) == 2
    demo = client.get("/api/demo/3").json()
    assert demo["length"] == len(demo["series"]) == len(demo["features"]) == st["lengths"][3]


def test_assign_skip_groups_gaps_are_saved_on_every_change(client, pool, tmp_path):
    out = tmp_path / "labelled.npz"
    assert not out.exists()
    st = client.post("/api/assign", json={"revision": 1, "ids": [0, 1, 2], "group": 1}).json()
    assert st["revision"] == 2 and st["saved_revision"] == 2 and st["group"][:3] == [1, 1, 1]
    saved = load_dataset(out, allow_unlabelled=True)
    assert saved.group[:3].tolist() == [1, 1, 1] and saved.n_unlabelled == 27
    assert saved.group_names == ("good", "bad", "very bad") and saved.env_id == "point_mass"
    st = client.post("/api/assign", json={"revision": 2, "ids": [3, 4], "group": 3}).json()
    st = client.post("/api/skip", json={"revision": st["revision"], "ids": [5], "skipped": True}).json()
    assert st["skipped"][5] and st["n_skipped"] == 1
    st = client.post("/api/gaps", json={"revision": st["revision"], "gap_relation": [1, 4]}).json()
    assert load_dataset(out, allow_unlabelled=True).gap_relation.tolist() == [1.0, 4.0]
    # rename keeps the gap relation; reorder (bad before good) and delete "very bad" clear it
    st = client.post("/api/groups", json={"revision": st["revision"], "names": ["fine", "bad", "very bad"]}).json()
    assert st["gap_relation"] == [1.0, 4.0]
    st = client.post("/api/groups", json={"revision": st["revision"], "names": ["bad", "fine", "new"],
                                          "source": [2, 1, None]}).json()
    assert st["group"][:5] == [2, 2, 2, 0, 0] and st["gap_relation"] is None
    saved = load_dataset(out, allow_unlabelled=True)
    assert saved.group_names == ("bad", "fine", "new") and saved.skipped[5]
    with pytest.raises(DatasetError, match="group 0"):
        load_dataset(out)  # not ready for inference yet


def test_reload_resumes_from_the_output(pool, tmp_path):
    out = tmp_path / "labelled.npz"
    with TestClient(create_app(LabelSession(pool[0], out)), base_url=BASE) as c:
        st = c.post("/api/groups", json={"revision": 1, "names": ["A", "B"], "source": [1, 2]}).json()
        st = c.post("/api/assign", json={"revision": st["revision"], "ids": [7, 8], "group": 2}).json()
        st = c.post("/api/gaps", json={"revision": st["revision"], "gap_relation": [2.5]}).json()
    again = LabelSession(pool[0], out)
    with TestClient(create_app(again), base_url=BASE) as c:
        st = c.get("/api/state").json()
    assert again.resumed and st["resumed"]
    assert [g["name"] for g in st["groups"]] == ["A", "B"] and st["group"][7:9] == [2, 2]
    assert st["gap_relation"] == [2.5]


def test_stale_revision_gets_409_and_changes_nothing(client, tmp_path):
    st = client.post("/api/assign", json={"revision": 1, "ids": [0], "group": 1}).json()
    before = (tmp_path / "labelled.npz").read_bytes()
    r = client.post("/api/assign", json={"revision": 1, "ids": [1], "group": 2})  # the other tab's old revision
    assert r.status_code == 409 and "another tab" in r.json()["error"] and "reload" in r.json()["error"]
    assert (tmp_path / "labelled.npz").read_bytes() == before
    assert client.get("/api/state").json()["revision"] == st["revision"]


def test_output_changed_by_another_program_gets_409(client, tmp_path):
    st = client.post("/api/assign", json={"revision": 1, "ids": [0], "group": 1}).json()
    out = tmp_path / "labelled.npz"
    time.sleep(0.01)
    out.write_bytes(out.read_bytes())  # same content, new file: another writer
    os.utime(out, ns=(1, 1))
    r = client.post("/api/assign", json={"revision": st["revision"], "ids": [1], "group": 1})
    assert r.status_code == 409 and "changed by another program" in r.json()["error"]


@pytest.mark.parametrize("path, body, status, match", [
    ("/api/assign", {"revision": 1, "ids": [999], "group": 1}, 422, "ids: unknown trajectory 999"),
    ("/api/assign", {"revision": 1, "ids": ["a"], "group": 1}, 422, "ids: 'a' is not a trajectory id"),
    ("/api/assign", {"revision": 1, "ids": [], "group": 1}, 422, "ids: expected a non-empty list"),
    ("/api/assign", {"revision": 1, "ids": [0], "group": 7}, 422,
     "group: expected 0 \\(unlabelled\\) or a group 1 to 3"),
    ("/api/assign", {"revision": 1, "ids": [0]}, 422, "group: missing"),
    ("/api/assign", {"ids": [0], "group": 1}, 400, "revision: missing"),
    ("/api/assign", {"revision": "1", "ids": [0], "group": 1}, 422, "revision: expected the integer"),
    ("/api/skip", {"revision": 1, "ids": [0], "skipped": "yes"}, 422, "skipped: expected true or false"),
    ("/api/groups", {"revision": 1, "names": ["a", "a"]}, 422, "names: group names must be unique"),
    ("/api/groups", {"revision": 1, "names": ["a", ""]}, 422, "names: group 2 needs a name"),
    ("/api/groups", {"revision": 1, "names": ["a", "b"], "source": [1, 1]}, 422, "source: group 1 is named twice"),
    ("/api/groups", {"revision": 1, "names": ["a"], "source": [9]}, 422, "source: 9 is not a current group"),
    ("/api/gaps", {"revision": 1, "gap_relation": [1]}, 422, "gap_relation: 3 groups need 2"),
    ("/api/gaps", {"revision": 1, "gap_relation": [1, -2]}, 422, "gap_relation: sizes must be positive"),
    ("/api/infer", {"iterations": 5}, 422, "iterations: expected an integer from 1,000"),
    ("/api/infer", {"chains": 2, "bogus": 1}, 422, "bogus: unknown setting"),
    ("/api/infer", {"figures": "yes"}, 422, "figures: expected true or false"),
    ("/api/infer", {}, 422, "group: inference needs at least two non-empty groups"),
])
def test_bad_requests_name_the_field(client, tmp_path, path, body, status, match):
    r = client.post(path, json=body)
    assert r.status_code == status
    assert re.search(match, r.json()["error"]), r.json()["error"]
    assert not (tmp_path / "labelled.npz").exists()  # nothing written


def test_bad_json_content_type_host_and_routes(client):
    r = client.post("/api/assign", content=b"{not json", headers={"Content-Type": "application/json"})
    assert r.status_code == 400 and r.json()["error"].startswith("body: not valid JSON")
    r = client.post("/api/assign", content=b"[1, 2]", headers={"Content-Type": "application/json"})
    assert r.status_code == 400 and r.json()["error"] == "body: expected a JSON object"
    r = client.post("/api/assign", content=b'{"revision": 1}', headers={"Content-Type": "text/plain"})
    assert r.status_code == 415 and "application/json" in r.json()["error"]
    assert client.get("/api/demo/30").status_code == 404
    assert "unknown trajectory" in client.get("/api/demo/abc").json()["error"]
    assert client.get("/api/nothing").status_code == 404
    assert client.get("/api/assign").status_code == 405
    assert client.get("/api/state", headers={"host": "evil.example"}).status_code == 400
    assert client.get("/api/figures/../../etc/passwd").status_code == 404
    assert client.get("/api/figures/trace.png").status_code == 404  # no run yet


def test_session_refuses_bad_input(tmp_path, pool):
    bad = tmp_path / "bad.npz"
    bad.write_text("hello")
    with pytest.raises(DatasetError, match="not a readable .npz"):
        LabelSession(bad, tmp_path / "o.npz")
    no_states = Dataset.from_trajectories([np.ones((3, 2))] * 4, [0, 0, 1, 2], allow_unlabelled=True)
    with pytest.raises(DatasetError, match="states: .* has no states"):
        LabelSession(no_states.save(tmp_path / "ns.npz"), tmp_path / "o.npz")
    with pytest.raises(DatasetError, match="out: .*expected a file name ending in .npz"):
        LabelSession(pool[0], tmp_path / "o.txt")
    with pytest.raises(DatasetError, match="out: .* is the input file"):
        LabelSession(pool[0], pool[0])
    other, _ = make_pool(tmp_path / "other.npz", n=20)
    with pytest.raises(DatasetError, match="out: .* holds 20 trajectories, the input has 30"):
        LabelSession(pool[0], other)


def test_cli_label_errors_and_export(tmp_path, pool, capsys):
    bad = tmp_path / "bad.npz"
    bad.write_text("hello")
    assert main(["label", str(bad), "--out", str(tmp_path / "o.npz"), "--no-browser"]) == 2
    assert "not a readable .npz" in capsys.readouterr().err
    assert main(["label", pool[0], "--no-browser"]) == 2
    assert "out: required" in capsys.readouterr().err
    # export: the labelled trajectories of a labelling file, ready for 'pbicrl infer'
    out = tmp_path / "labelled.npz"
    s = LabelSession(pool[0], out)
    st = s.assign(1, [0, 1], 1)
    st = s.assign(st["revision"], [2, 3], 2)
    s.skip(st["revision"], [4])
    assert main(["label", str(out), "--export", str(tmp_path / "ready.npz")]) == 0
    ready = load_dataset(tmp_path / "ready.npz")
    assert ready.n_trajectories == 4 and ready.group_names == ("good", "bad")


@pytest.mark.parametrize("figures", [False, pytest.param(True, marks=pytest.mark.slow)])
def test_run_inference_from_the_page(pool, tmp_path, figures):
    out = tmp_path / "labelled.npz"
    session = LabelSession(pool[0], out)
    truth = pool[1]
    with TestClient(create_app(session), base_url=BASE) as c:
        rev = 1
        for g in (1, 2, 3):
            ids = [int(i) for i in np.flatnonzero(truth == g)[:6]]
            rev = c.post("/api/assign", json={"revision": rev, "ids": ids, "group": g}).json()["revision"]
        r = c.post("/api/infer", json={"iterations": 2000, "chains": 1, "n_suggest": 3, "figures": figures})
        assert r.status_code == 202 and r.json()["status"] == "running"
        again = c.post("/api/infer", json={"iterations": 2000, "chains": 1})
        assert again.status_code == 409 and "already running" in again.json()["error"]
        deadline = time.monotonic() + 300
        while (job := c.get("/api/infer").json())["status"] == "running":
            assert time.monotonic() < deadline, job
            time.sleep(0.3)
        assert job["status"] == "done", job["message"]
        # issue 30 item 5: the time stops with the run (it grew on every reload) and the settings are shown
        time.sleep(0.3)
        assert c.get("/api/infer").json()["elapsed_s"] == job["elapsed_s"]
        assert job["settings"] == {"iterations": 2000, "chains": 1, "margins": None, "seed": 0, "n_suggest": 3,
                                   "figures": figures}
        res = job["result"]
        assert [f["name"] for f in res["features"]] == list(pbicrl.load_dataset("point_mass").feature_names)
        assert all(0.0 <= f["p_constraint"] <= 1.0 for f in res["features"])
        assert [g["n"] for g in res["groups"]] == [6, 6, 6] and job["revision"] == rev
        assert len(res["suggestions"]["suggestions"]) == 3
        picks = [s["index"] for s in res["suggestions"]["suggestions"]]
        assert all(0 <= i < truth.size and session.group[i] == 0 for i in picks)
        run = read_run(res["run_dir"])
        assert run.data_path is not None and load_dataset(run.data_path).n_trajectories == 18
        if not figures:
            assert res["figures"] == []
        elif res["figures"]:
            img = c.get(f"/api/figures/{res['figures'][0]}")
            assert img.status_code == 200 and img.headers["content-type"] == "image/png"
            assert img.content[:4] == b"\x89PNG"
        else:  # no matplotlib
            assert "figures_note" in res
