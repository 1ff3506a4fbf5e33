"""The parts every long training run shares: stop signals, the session clock, the progress log, the recorded
versions."""

from __future__ import annotations

import os
import re
import signal
import threading

from pbicrl.baselines.session import SessionClock, StopSignals, library_versions, progress_logger


def test_sigterm_and_sigint_become_a_stop_request_until_restored():
    before = {sig: signal.getsignal(sig) for sig in (signal.SIGTERM, signal.SIGINT)}
    stop = StopSignals().install()
    try:
        assert not stop.requested
        os.kill(os.getpid(), signal.SIGTERM)  # the process lives on: the handler only notes the request
        assert stop.requested
        stop.requested = False
        os.kill(os.getpid(), signal.SIGINT)  # no KeyboardInterrupt either
        assert stop.requested
    finally:
        stop.restore()
    assert {sig: signal.getsignal(sig) for sig in before} == before
    stop.restore()  # a second restore changes nothing
    assert {sig: signal.getsignal(sig) for sig in before} == before


def test_a_request_without_a_signal_and_no_handlers_outside_the_main_thread():
    before = signal.getsignal(signal.SIGTERM)
    seen = {}

    def in_thread() -> None:
        s = StopSignals().install()  # signal.signal refuses outside the main thread: nothing is installed
        seen["handler"] = signal.getsignal(signal.SIGTERM)
        s.request()
        seen["requested"] = s.requested
        s.restore()

    t = threading.Thread(target=in_thread)
    t.start()
    t.join()
    assert seen == {"handler": before, "requested": True}
    assert signal.getsignal(signal.SIGTERM) == before


def test_the_progress_log_appends_timestamped_lines_and_echoes_only_when_asked(tmp_path, capsys):
    path = tmp_path / "progress.log"
    quiet = progress_logger(path, echo=False)
    quiet("first")
    assert capsys.readouterr().err == ""
    progress_logger(path, echo=True)("second")  # a resumed run appends to the same file
    lines = path.read_text().splitlines()
    stamp = r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\dZ"
    assert [re.fullmatch(rf"{stamp} (\w+)", ln).group(1) for ln in lines] == ["first", "second"]
    assert capsys.readouterr().err == lines[1] + "\n"


def test_versions_leave_out_or_note_a_library_that_is_missing():
    name = "pbicrl_no_such_module_for_versions"
    assert set(library_versions(("numpy", name))) == {"python", "numpy"}
    noted = library_versions(("numpy", name), note_failures=True)
    assert noted[name] == "unknown (ModuleNotFoundError)"
    assert noted["numpy"] == __import__("numpy").__version__
    # the default set is what ICL and train-safe record
    assert {"python", "numpy"} <= set(library_versions()) <= {"python", "numpy", "torch", "gymnasium", "mujoco"}


def test_the_session_clock_checkpoints_every_n_steps_and_ends_a_limited_session():
    saved: list[tuple[str, int]] = []
    steps = {"now": 1000}  # a resumed run: the session starts at 1000 steps
    stop = StopSignals()
    clock = SessionClock(lambda status: saved.append((status, steps["now"])), stop, 1000, every=300,
                         max_session_steps=700)
    for now in (1200, 1300, 1500, 1550):
        steps["now"] = now
        assert clock.tick(now)
    assert saved == [("running", 1300)]  # 300 steps after the start, then not again until 1600
    steps["now"] = 1700
    assert not clock.tick(1700)  # 700 steps in this session: stop, after the checkpoint
    assert saved == [("running", 1300), ("running", 1700)] and stop.requested
    unlimited = SessionClock(lambda status: None, StopSignals(), 0, every=10)
    assert unlimited.tick(10**9)
