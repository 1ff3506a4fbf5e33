"""``python -m pbicrl.envs ...``: see :mod:`pbicrl.envs.cli`."""

from pbicrl.envs.cli import main

raise SystemExit(main())
