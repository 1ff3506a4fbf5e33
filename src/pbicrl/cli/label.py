"""Subcommands ``pbicrl label`` (the labelling web app), ``pbicrl pool`` (demonstrations to label, from any dataset)
and ``pbicrl suggest`` (what to label next).

Registered by :mod:`pbicrl.cli` through ``add_subcommands``; nothing optional is imported until a command runs.
"""

from __future__ import annotations

import argparse
import errno
import json
import socket
import sys
import threading
from pathlib import Path
from typing import Any

from pbicrl.cli.argtypes import port, positive_int as _positive_int

__all__ = ["add_subcommands", "check_port"]


def add_subcommands(sub: Any) -> None:
    """Add ``label``, ``pool`` and ``suggest`` to the ``pbicrl`` subparsers."""
    p = sub.add_parser("label", help="rank demonstrations in the browser (needs pbicrl[ui])",
                       description="Start a local web app that shows each demonstration, lets you sort them into "
                                   "ranked groups (drag, or keys 1-9), skip some, state the gap relation, and run "
                                   "inference; every change is saved to --out, which also resumes a session.")
    p.add_argument("data", type=Path, help="demonstrations (.npz with states; group 0 = unlabelled) or a shipped name")
    p.add_argument("--out", type=Path, help="labelled dataset (.npz), written on every change; resumed if it exists")
    p.add_argument("--port", type=port, default=8000, help="port (default 8000; 0 = any free port)")
    p.add_argument("--host", default="127.0.0.1", help="address to listen on (default 127.0.0.1: this machine only)")
    p.add_argument("--allow-host", action="append", default=[], metavar="NAME",
                   help="a host name clients may use (repeat, or comma-separated); required with a --host other "
                        "than a loopback address, where only these names are accepted")
    p.add_argument("--no-browser", action="store_true", help="do not open a browser")
    p.add_argument("--env", dest="env_id", help="environment for the pictures (default: the dataset's env_id)")
    p.add_argument("--export", type=Path, metavar="FILE",
                   help="instead of serving: write DATA's labelled trajectories (skipped and unlabelled ones "
                        "dropped) to FILE, a dataset that 'pbicrl infer' reads, and exit")
    p.add_argument("--overwrite", action="store_true", help="--export: replace an existing FILE (never DATA itself)")
    p.set_defaults(func=_cmd_label)

    q = sub.add_parser("pool", help="an unlabelled pool for 'pbicrl label' from a dataset (yours or a shipped one)",
                       description="Draw --n demonstrations from DATA without replacement (all without --n), set "
                                   "every group to 0 (unlabelled) and write them to --out. States, features and the "
                                   "environment (env_id) are kept, so 'pbicrl label' draws the goal and regions.")
    q.add_argument("data", type=Path, help="dataset .npz or a shipped name (e.g. point_mass)")
    q.add_argument("--n", type=_positive_int, help="how many demonstrations (default: all)")
    q.add_argument("--seed", type=int, default=0, help="seed of the draw (default 0)")
    q.add_argument("--out", type=Path, required=True, help="the pool (.npz)")
    q.add_argument("--overwrite", action="store_true", help="replace an existing --out")
    q.set_defaults(func=_cmd_pool)

    s = sub.add_parser("suggest", help="which unlabelled demonstrations to label next (active query selection)",
                       description="Rank the pool's unlabelled demonstrations by the expected information their "
                                   "group gives about the constraint indicators, from the run's posterior draws.")
    s.add_argument("run", type=Path, help="run directory of 'pbicrl infer'")
    s.add_argument("--pool", type=Path, required=True,
                   help="demonstrations to choose from (.npz; group 0 = unlabelled)")
    s.add_argument("--n", type=_positive_int, default=5, help="how many to suggest (default 5)")
    s.add_argument("--data", type=Path, help="the run's labelled dataset (default: the one the run records)")
    s.add_argument("--target", choices=["indicators", "selected"], default="indicators",
                   help="information about the indicator vector c (default) or about each P(c_j=1)")
    s.add_argument("--draws", type=_positive_int, default=200, help="posterior draws used (default 200)")
    s.add_argument("--json", action="store_true", help="print JSON instead of the table")
    s.add_argument("--allow-unconverged", action="store_true",
                   help="rank from a run that did not converge (refused by default)")
    s.set_defaults(func=_cmd_suggest)


def check_port(host: str, port: int) -> None:
    """Raise a :class:`ValueError` naming ``--port`` if the address cannot be bound."""
    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)
    except socket.gaierror as exc:
        raise ValueError(f"host: cannot resolve {host!r} ({exc.strerror})") from None
    family, _, _, _, addr = infos[0]
    with socket.socket(family, socket.SOCK_STREAM) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind(addr)
        except OSError as exc:
            if exc.errno == errno.EADDRINUSE:
                raise ValueError(f"port: {port} is in use on {host}; pass another --port (0 picks a free one)") \
                    from None
            raise ValueError(f"host: cannot listen on {host}:{port} ({exc.strerror or exc})") from None


def _cmd_label(args: argparse.Namespace) -> int:
    from pbicrl.inference.data import load_dataset

    if args.export is not None:
        from pbicrl._atomic import check_file_output
        from pbicrl.inference.data import resolve_dataset_path

        if args.export.suffix != ".npz":
            raise ValueError(f"export: {args.export}: expected a file name ending in .npz")
        data = resolve_dataset_path(args.data)
        # the labelled subset over its own pool (or over any file) would lose what it leaves out
        check_file_output(args.export, overwrite=args.overwrite, inputs=[data, args.out], field="--export")
        ds = load_dataset(data, allow_unlabelled=True)
        out = ds.labelled()
        path = out.save(args.export, overwrite=args.overwrite)
        print(f"wrote {path}: {out} ({ds.n_unlabelled} unlabelled or skipped trajectories left out)")
        return 0
    if args.out is None:
        raise ValueError("out: required (the labelled dataset, e.g. --out labelled.npz)")
    allow_hosts = [h.strip() for a in args.allow_host for h in a.split(",") if h.strip()]
    from pbicrl.ui.server import LOOPBACK_HOSTS

    if args.host not in LOOPBACK_HOSTS and not allow_hosts:
        raise ValueError(f"allow-host: listening on {args.host!r} (not this machine only) needs the host names "
                         "clients will use: --allow-host NAME (anyone who reaches them can change the labels)")
    from pbicrl.ui import require_ui_extra

    require_ui_extra()
    import uvicorn

    from pbicrl.ui.server import create_app
    from pbicrl.ui.session import LabelSession

    session = LabelSession(args.data, args.out, env_id=args.env_id)
    port = args.port
    if port == 0:
        with socket.socket() as s:
            s.bind((args.host, 0))
            port = s.getsockname()[1]
    check_port(args.host, port)
    app = create_app(session, host=args.host, allow_hosts=allow_hosts)
    shown = f"[{args.host}]" if ":" in args.host else args.host
    url = f"http://{shown}:{port}/"
    state = session.state()
    print(f"pbicrl label: {session.source} -> {session.out}"
          f"{' (resumed)' if session.resumed else ''}: {state['n']} demonstrations, {state['n_unlabelled']} "
          f"unlabelled; open {url} (Ctrl-C stops)", file=sys.stderr)
    if args.host not in LOOPBACK_HOSTS:
        print(f"warning: listening on {args.host}: anyone who reaches this address can change the labels (the "
              "page has no login)", file=sys.stderr)
    if not args.no_browser:
        import webbrowser

        threading.Timer(1.0, lambda: webbrowser.open(url)).start()
    uvicorn.run(app, host=args.host, port=port, log_level="warning")
    return 0


def _cmd_pool(args: argparse.Namespace) -> int:
    from pbicrl.inference.data import load_dataset, resolve_dataset_path

    if args.out.suffix != ".npz":
        raise ValueError(f"out: {args.out}: expected a file name ending in .npz")
    src = resolve_dataset_path(args.data)
    if args.out.exists() and args.out.resolve() == src.resolve():
        raise FileExistsError(f"out: {args.out} is the input dataset; choose another file")
    if args.out.exists() and not args.overwrite:
        raise FileExistsError(f"out: {args.out} already exists; choose another file or pass --overwrite")
    pool = load_dataset(src, allow_unlabelled=True).as_pool(args.n, seed=args.seed)
    path = pool.save(args.out, overwrite=args.overwrite)
    env = f"env_id {pool.env_id!r}" if pool.env_id else "no env_id (pass --env ENV to 'pbicrl label')"
    print(f"wrote {path}: {pool.n_trajectories} unlabelled demonstrations from {src.name}, {env}")
    return 0


def _cmd_suggest(args: argparse.Namespace) -> int:
    from pbicrl.analysis.suggest import suggest_run

    res = suggest_run(args.run, args.pool, args.n, data=args.data, target=args.target, max_draws=args.draws,
                      allow_unconverged=args.allow_unconverged)
    if args.json:
        print(json.dumps(res.to_dict(), indent=2, allow_nan=False))
    else:
        print(res.table())
    return 0
