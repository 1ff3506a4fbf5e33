"""``python -m pbicrl.envs ...``: see :mod:`pbicrl.cli.navigation`."""

from pbicrl.cli.navigation import main

raise SystemExit(main())
