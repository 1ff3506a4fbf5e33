"""``python -m pbicrl.demonstrators ...``: see :mod:`pbicrl.cli.wall`."""

from pbicrl.cli.wall import main

raise SystemExit(main())
